"""Correction with whole-body inverse kinematics (the paper's section 3).

* :mod:`.constraints`: Cartesian constraints (a joint, a goal, a time range with eased entry
  and exit), one module per kind.
* :mod:`.ik`: equation (1), damped least squares with priority levels and the attraction to
  the converted posture.
* :mod:`.enforcement`: the two passes of section 3.3 over a clip.
* :mod:`.displacement`: the correction stored as editable per-channel curves.
* :mod:`.contacts`: automatic foot contacts found in the performer's motion.
"""
