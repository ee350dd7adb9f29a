"""Motion Composer: retarget captured motion onto any character through an intermediate
skeleton, then correct it with whole-body IK.

The one import name of the installed program. Its parts are the repository's top-level
folders, linked in here: :mod:`motion_composer.engine` (numpy and scipy only),
:mod:`motion_composer.app` (the command line and the window) and ``resources/`` (the demo
project, bundled clips and characters, the icon), which the wheel carries as package data.
"""
__version__ = "0.1.0"
