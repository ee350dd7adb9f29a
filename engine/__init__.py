"""Motion Composer's engine: skeletons, motions, file formats, kinematics and retargeting.

Pure numpy and scipy: this package never imports Qt, pyqtgraph or OpenGL (a test enforces it),
so it serves the desktop application, the command line and batch jobs alike.

Internal convention, everywhere: metres, +Y up, right-handed; rotations as unit quaternions
x, y, z, w; arrays ``(frames, joints, ...)``. See :mod:`engine.units`.
"""
from .formats.bvh import parse_bvh, read_bvh, write_bvh
from .errors import BVHError, ExportError, FileFormatError, MotionComposerError, SkeletonError
from .kinematics import WorldPose, forward_kinematics
from .motion import Motion
from .skeleton import EndSite, Skeleton
from .units import SourceFrame

__all__ = [
    "Motion", "Skeleton", "EndSite", "SourceFrame", "WorldPose",
    "read_bvh", "parse_bvh", "write_bvh", "forward_kinematics",
    "MotionComposerError", "FileFormatError", "BVHError", "ExportError", "SkeletonError",
]
__version__ = "0.1.0"
