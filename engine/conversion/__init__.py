"""Direct motion conversion through an Intermediate Skeleton (the paper's section 2).

* :mod:`.correspondence` and :mod:`.automap`: the node-to-node correspondence (target joint ->
  performer joint), set by hand or found from structure and names.
* :mod:`.binding` (*Anatomic Binding*, 2.1): builds the :class:`Binding`, our Intermediate
  Skeleton: the target's joints and local axes, its bones laid along the performer's virtual
  bones in the reference pose (rest-posture alignment).
* :mod:`.converter` (*Motion Converter*, 2.2): orients every intermediate bone along its
  virtual bone, every frame.
* :mod:`.composer` (*Motion Composer*, 2.3): copies the intermediate local values onto the
  target.
"""
from .automap import automap
from .binding import BindOptions, Binding, bind, is_upright, reference_pose
from .composer import compose, retarget
from .converter import IntermediatePose, RootOptions, convert
from .correspondence import Correspondence

__all__ = ["Correspondence", "automap", "BindOptions", "Binding", "bind", "is_upright",
           "reference_pose", "IntermediatePose", "RootOptions", "convert", "compose",
           "retarget"]
