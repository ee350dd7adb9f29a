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

The binding is computed once; conversion and composition are vectorised over frames.
:func:`retarget` runs bind, convert and compose.

How each mapped joint turns (its world rotation is ``delta * A`` with ``A`` its bound rest
rotation): ``delta`` is the rotation taking the joint's virtual bones in the performer's
reference pose to where they are in the frame. The *primary* virtual bone (the one leading to
the child with the largest subtree, e.g. the spine for the hips) is matched exactly by the
smallest swing. The roll about it, which the paper leaves out, is carried where the data
allows: by the other virtual bones of a branching joint (the hip line for the hips, the
shoulder line for the chest), else by the twist of the performer joint's own rotation (which
carries a forearm's or a foot's roll), so a clip retargeted onto its own skeleton comes back
unchanged. A joint with no usable virtual bone (a leaf, or a zero-length bone) takes the
performer joint's whole rotation change.

Unmapped target joints keep their bound local rotation (they follow their parent). Where a
target chain has more joints than the performer maps (CC3's spine under CMU's), the
``distribute="even"`` default spreads the chain's turn evenly over its joints and then corrects
the chain so that its end still lies exactly along the virtual bone; ``"first"`` puts it all on
the chain's first joint. A branching joint keeps its whole turn (it also places its other bones:
a hand's thumb does not hang from the metacarpal of its primary finger), so its twist is kept.

The animator's hand on the binding (:attr:`BindOptions.pose_offsets`, :attr:`BindOptions.chains`,
:mod:`.chains`): a *pose offset* ``q`` on joint ``j`` turns ``j`` in its binding frame, so the
*binding pose* (``Binding.rest_local``) is ``rest_local * q``. The converter turns the
bound posture before the offsets as above, then takes each joint's per-frame local rotation
``L`` relative to its parent and makes it ``L * q``: the joint's local rotation changes by
exactly that rotation in the binding frame on every frame, and no other joint's does (its
children keep their local rotations and follow it rigidly, so the limb below turns with it).
Per-chain settings act on the same local rotations, before the offset: with ``twist`` off a
chain joint's rotation relative to its bound rest one loses its twist about the joint's bone
(towards its child with the largest subtree: swing-twist relative to the binding); the
``weight`` slerps each chain joint's local rotation from its bound rest value (0: exactly the
binding pose on every frame, bit for bit: ``Binding.held``) to the converted one (1); a chain's own ``distribute`` replaces
the global one for the unmapped joints below its mapped ones. Defaults change nothing, bit
for bit. A chain's ``ik_blend`` is not the converter's: it adds a reach goal to the IK
(:mod:`engine.correction.reach`).
"""
from .automap import automap
from .binding import BindOptions, Binding, bind, is_upright, reference_pose
from .chains import (CHAINS, ChainSettings, chain_of_joint, chains_of, effector,
                     euler_to_offset, mirror_joint, mirrored_offset, offset_to_euler)
from .composer import compose, retarget, transfer
from .converter import IntermediatePose, RootOptions, convert
from .correspondence import Correspondence

__all__ = ["Correspondence", "automap", "BindOptions", "Binding", "bind", "is_upright",
           "reference_pose", "IntermediatePose", "RootOptions", "convert", "compose",
           "retarget", "transfer", "CHAINS", "ChainSettings", "chains_of", "chain_of_joint",
           "effector", "mirror_joint", "mirrored_offset", "euler_to_offset",
           "offset_to_euler"]
