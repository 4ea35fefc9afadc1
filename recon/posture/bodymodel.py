"""The standard body model: average adult-male section sizes and joint layout (paper section 2.1).

Sizes are for the average adult male, stature ``STATURE`` = 1.75 m, and scale with one factor for
other bodies (`standard_body`). Sources:

- Segment lengths as fractions of stature from Winter, *Biomechanics and Motor Control of Human
  Movement*, 4th ed. (2009), Fig. 4.1 / Table 4.1 (after Drillis & Contini 1966): shoulder height
  0.818 H, hip (greater trochanter) 0.530 H, knee 0.285 H, ankle 0.039 H, thigh 0.245 H, leg 0.246 H,
  forearm 0.146 H, hand 0.108 H, biacromial width 0.259 H, hip width 0.191 H.
- The joint *centres* follow the body file format's rig (the MakeHuman/anny default skeleton whose bone
  heads are the ground-truth joints), which places some joints differently from Winter's anatomical
  landmarks: the shoulder joint lower and more medial (upper arm 0.155 H rather than 0.186 H), the
  spine joints pelvis (root) 0.53 H, chest (spine01) 0.738 H, neck (neck01) 0.851 H, head 0.908 H,
  and the joints lie off the sections' axes and ends (`JOINT_OFFSET`). These fractions are the mean of
  two of the rig's bodies in rest and standing pose; the fit uses them as a start and for joints
  that the surface cannot show (where along a straight limb the elbow is).
- Radii (half widths and depths of the cross-sections) are rounded from mean adult-male breadths,
  depths and circumferences (ANSUR II, Gordon et al. 2014): chest breadth 0.33 m, chest depth 0.25 m,
  waist breadth 0.31 m, waist depth 0.22 m, head breadth 0.155 m and length 0.195 m, biceps
  circumference 0.32 m, forearm circumference 0.29 m, thigh circumference 0.58 m, calf 0.38 m (the
  model's columns take the mean radius along the section, so limb radii are below the maxima).

The model is described in its own frame: x to the subject's left, y to the back, z up (the subject
faces -y), with the pelvis joint at the origin. The measurements behind the chosen values are in
docs/tuning.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Stature of the standard body, metres (average adult male).
STATURE = 1.75

#: Statures the fit sizes a body within, metres: a small child to a tall adult (the corpus draws
#: anny's whole height range, 1.1 to 2.8 m tall, standing; sizing beyond 2.2 m gained no tune body).
STATURE_RANGE = (0.8, 2.2)

#: Limb chains: (proximal section, distal section, root joint, middle joint, end joint on the distal).
LIMBS = (
    ("upper_arm_l", "forearm_l", "shoulder_l", "elbow_l", "wrist_l"),
    ("upper_arm_r", "forearm_r", "shoulder_r", "elbow_r", "wrist_r"),
    ("thigh_l", "lower_leg_l", "hip_l", "knee_l", "ankle_l"),
    ("thigh_r", "lower_leg_r", "hip_r", "knee_r", "ankle_r"),
)

# fractions of stature H
_F = dict(
    chest=0.738 - 0.53,      # pelvis -> chest joint (spine01)
    neck=0.851 - 0.53,       # pelvis -> neck joint (neck01)
    head_joint=0.057,        # neck joint -> head joint, along the head section
    head=1.0 - 0.851,        # neck joint -> top of head (head section, neck included)
    shoulder_z=0.797 - 0.53,  # pelvis -> shoulder joints, up
    shoulder_x=0.105,        # half distance between the shoulder joints
    hip_z=-0.003,            # pelvis -> hip joints, up
    hip_x=0.064,             # half distance between the hip joints
    upper_arm=0.155,         # shoulder -> elbow
    forearm=0.145,           # elbow -> wrist
    hand=0.108,              # wrist -> fingertip (Winter)
    thigh=0.235,             # hip -> knee
    lower_leg=0.250,         # knee -> ankle
    foot_height=0.043,       # ankle -> sole
)

#: Where the sections meet (`recon.posture.joints.place_seams`, the clustering's joint planes): the
#: spine's seams lie behind the torso's axis (towards the back), as fractions of stature, where the
#: rig's spine joints lie on two of its average bodies. The head's is measured from the fitted head
#: column instead (0.011 H on the rig's surfaces): the mean offset, front-back, of the rig's head
#: joint from the fitted column's axis 0.057 H above the neck on `paper` scans (k = 1 and 3) of two
#: of the rig's bodies, standing and a_pose (0.3 cm back; the 0.011 H placed it 1.6 cm too far back,
#: on those and over the library alike).
SPINE_BACK = dict(pelvis=0.007, chest=0.045, neck=0.020, head=0.002)

#: Where the rig's joints lie relative to the fitted sections (`recon.posture.joints.offset_joints`,
#: the reported joints, `recon.model.BodyFit.joints`): joint kind -> ((out, back, along), (out,
#: back, along)), in the frame of the joint's section (`recon.posture.joints.joint_frame`:
#: outwards, towards the subject's back, along its axis), as fractions of stature at ``STATURE``,
#: and their change per unit of ``stature / STATURE - 1``. The joints are first found on the
#: sections' axes and ends (the pelvis at the waist column's lower end, a hip at its thigh's top, a
#: knee where thigh and lower leg meet or closing the leg's triangle...); the rig's joints lie off
#: those points: the spine's behind the torso's axis, the femoral heads behind the thighs' tops,
#: the wrists outwards of the forearm's axis. And they drift with size: the model's proportions are
#: one adult's, scaled, while a child's head is relatively larger and its legs shorter, a tall
#: adult's legs longer (the rig's hip joint at 0.50 of stature on its children, 0.56 on its 2.1 m
#: adults). Estimated by robust least squares (soft L1 at 2 cm) on the tune corpus (seed 0, 62
#: bodies; `paper` scans at 10 mm, k = 1 and 3, and 36 of them turned 90 degrees at k = 1), on the
#: fits with a median joint error up to 6 cm and their joints within 10 cm of the truth.
JOINT_OFFSET = dict(
    pelvis=((0.0, 0.0076, 0.0039), (0.0, -0.0046, 0.0556)),
    chest=((0.0, 0.0390, 0.0101), (0.0, -0.0222, 0.0186)),
    neck=((0.0, 0.0165, 0.0027), (0.0, -0.0040, 0.0120)),
    head=((0.0, 0.0029, 0.0064), (0.0, 0.0089, -0.0160)),
    shoulder=((-0.0026, -0.0055, 0.0049), (-0.0114, 0.0018, 0.0227)),
    elbow=((0.0031, 0.0032, -0.0005), (0.0003, 0.0043, -0.0016)),
    wrist=((0.0139, 0.0, -0.0037), (-0.0062, 0.0026, 0.0275)),
    hip=((0.0035, 0.0176, -0.0014), (-0.0084, 0.0049, 0.0504)),
    knee=((0.0015, 0.0087, 0.0028), (-0.0117, 0.0103, 0.0943)),
    ankle=((-0.0024, 0.0086, 0.0009), (0.0162, 0.0105, 0.0135)),
)

#: Where the chest section meets the waist section, as a fraction of the fitted waist column (pelvis
#: joint to chest joint), when no crotch is seen (`recon.posture.joints.split_torso`; hips flexed): the
#: body file format labels the spine02 bone and above as chest, and its head lies below the rig's
#: chest joint (spine01), where the model's two torso columns are joined. Along the rig's own
#: pelvis-chest joint line the plane that best separates the labels lies at 0.625 (standing and
#: a_pose, 0.8 % of torso vertices on the wrong side; 0.57 to 0.68 over the library); the cut is
#: made across the fitted waist column, which runs up the torso's middle, while the rig's chest
#: joint lies 0.045 H behind it (`SPINE_BACK`): measured across the column, with the rig's joints
#: projected on it, the best plane lies at 0.68 (standing 0.682, a_pose 0.676). (chosen) 0.65 on
#: the 13 average-male bodies.
TORSO_SPLIT = 0.65

#: Where the chest section meets the waist section, as a fraction of the way from the crotch seen
#: in the points (`recon.posture.joints.find_crotch`) to the fitted chest joint, measured along the waist
#: column (`recon.posture.joints.split_torso`). The fitted pelvis joint, the column's lower end, rides with
#: the waist and is the torso's worst-placed landmark along its axis (-3.2 to +4.2 cm against the
#: rig's over the library, estimated posture), while the crotch is seen on the points (within -1.1
#: to +1.9 cm of the rig's, `CROTCH_STRIP`). (chosen) 0.73 on the 13 average-male bodies.
TORSO_SPLIT_CROTCH = 0.73

#: The cut of the torso stays within this fraction of the fitted waist column (from its pelvis end):
#: the best cuts for the labels lie at 0.52 to 0.74 of it over the library's fits; a crotch found
#: far off (a stray point between the thighs) must not move the boundary off the waist.
TORSO_SPLIT_RANGE = (0.5, 0.8)

#: The body file's lower-leg labels start below the rig's knee joint, along the shank, by this
#: fraction of stature: 3.9 cm (0.022 H) on standing and a_pose, 1.6 to 3.9 cm over the library's
#: straight legs. The fit places the knee joint; its reported lower legs start this much lower.
KNEE_SPLIT = 0.022

#: The reported thighs start at most this many thigh lengths (hip to knee) above the crotch seen in
#: the points, along the thigh (`recon.posture.joints.split_hips`): the body file labels the buttocks and
#: the groin waist down to the crotch, and thigh only from a slanted boundary above it (its topmost
#: thigh vertex, on the hip's side, 0.16-0.18 thigh lengths above the crotch on the adult rig's
#: upright bodies, 0.22-0.28 on heavy, child and woman bodies). (chosen) 0.12, a cross-section
#: below that top.
CROTCH_SPLIT = 0.12

#: How far the rig's pelvis joint lies above the crotch seen in the points (`recon.posture.joints.
#: find_crotch`), along the waist's axis, in statures (`recon.posture.joints.pelvis_from_below`):
#: the median over the tune corpus's fits (seed 0, bodies 0-61, paper 10 mm, k = 1-3 and turned;
#: 152 fits with a crotch found: 0.055 mean, 0.017 sd). Anthropometry agrees: the root joint at
#: 0.53 statures (above), the crotch at about 0.47.
PELVIS_ABOVE_CROTCH = 0.052

#: How far the rig's pelvis and hip joints lie above the seat seen in the points with the hips
#: flexed (`recon.posture.joints.find_seat`: the lowest point of the buttocks), along the waist's
#: axis, in statures (`recon.posture.joints.pelvis_from_below`): the medians over the tune corpus's
#: fits with the hips flexed and no crotch.
ABOVE_SEAT = dict(pelvis=0.052, hip=0.046)

#: Where the seat is sought (`recon.posture.joints.find_seat`): along the waist's axis, from its
#: lower end, in statures (wide enough for a squat's waist column run on 10-15 cm into the
#: buttocks: its seat then lies up to about 0.15 statures below the column's end, and an empty
#: ``step`` must follow it within the window), and across it, within this
#: fraction of the waist's larger radius of its mid-plane (between the buttocks' cleft and the
#: thighs' sides; chosen on the tune corpus).
SEAT_WINDOW = (-0.2, 0.05)
SEAT_STRIP = 0.5

#: Half-width of the strip about the mid-plane between the thighs in which the crotch is sought,
#: in the thinner thigh's radii. (chosen) 0.12 (about 1 cm, twice the `paper` scan's spacing):
#: the crotch found within -1.1 to +1.9 cm of the rig's (lowest waist vertex on the mid-plane) on
#: eight upright bodies; a strip of 0.3 radii took the inner thighs of legs held close, 2-6 cm low.
CROTCH_STRIP = 0.12

#: Height of a section's cap where it meets another section at a joint, in minor radii: flat, so
#: that it does not reach far into the neighbour (a hemisphere at the hip reached 9 cm into the
#: waist). Free ends (the pelvis end of the waist, head top, fingertips, soles) keep their caps.
JOINT_CAP = 0.5

#: The reported upper arm's cross-section radii, front to back and across, as multiples of the
#: fitted (round) radius (`recon.posture.joints.shape_limbs`): the upper arm is deeper front to back
#: than across (biceps and triceps; the deltoid over the joint): the oracle's sections (principal
#: radii of the labels' cross-sections) measure 1.16-1.25 times deeper than wide on all 21 shipped
#: bodies. The product is 1 (the fitted area is kept). (chosen) ratio 1.30 on the 13 average-male
#: bodies.
UPPER_ARM_SHAPE = (1.14, 0.877)

#: The reported upper arm's start cap at the shoulder, in minor radii: ``SHOULDER_CAP[0] +
#: SHOULDER_CAP[1] * cos``, ``cos`` between the arm's axis and the chest's downward axis
#: (`recon.posture.joints.joint_caps`). The body file labels the deltoid upper arm; it covers the joint
#: from above, so the labels reach past the joint along a hanging arm's axis (the oracle's upper
#: arms start 0.038-0.040 statures before the joint on the standing bodies) more than along one
#: held sideways (t_pose 0.026) or raised (0.016-0.018). (chosen) with the arm shape 1.3.
SHOULDER_CAP = (0.6, 0.6)

#: The reported lower leg's cross-section radii, front to back and across, as multiples of the
#: fitted (round) radius (`recon.posture.joints.shape_limbs`): the calf lies behind the shin bone; the
#: oracle's sections measure 1.08-1.23 times deeper than wide (1.16 on the 1.76 m male rig) on the
#: 21 shipped bodies (squat, whose foot folds under the thigh, aside). The product is 1.
#: (chosen) ratio 1.30, as the upper arm's.
LOWER_LEG_SHAPE = (1.14, 0.877)

#: Where the sections meet (`recon.posture.joints.place_seams`): the hips' seams lie behind and
#: outside the top of the thigh's column, where the rig's hip joints (femoral heads) lie on two of
#: its average bodies, as fractions of stature: the mean offset from the fitted thigh start to the
#: rig's hip joint on `paper` scans (k = 1 and 3) of two of the rig's bodies, standing and a_pose
#: (4.1 cm back, 2.2 cm out for a 1.76 m body; sd 1.1 and 1.2 cm). Measured on the posture's frame,
#: so it holds for a thigh raised or turned.
HIP_OFFSET = dict(back=0.023, out=0.0127)

# radii (a across, b front-back), metres for the 1.75 m body
_R = dict(
    head=(0.078, 0.092), chest=(0.160, 0.115), waist=(0.150, 0.110),
    upper_arm=(0.045, 0.045), forearm=(0.037, 0.037), thigh=(0.075, 0.075), lower_leg=(0.050, 0.050),
)


@dataclass(frozen=True)
class StandardBody:
    """The standard model scaled to one stature: joint offsets, section lengths and radii.

    Attributes
    ----------
    stature : float
        Metres.
    """

    stature: float = STATURE

    @property
    def scale(self) -> float:
        """Stature relative to the average adult male."""
        return self.stature / STATURE

    def length(self, key: str) -> float:
        """A length of the model, metres: any key of the fraction table (``upper_arm``, ``neck``...)."""
        return _F[key] * self.stature

    def radii(self, kind: str) -> np.ndarray:
        """(2,) radii of a section kind (``head``, ``chest``, ``waist``, ``upper_arm``...), metres."""
        return np.asarray(_R[kind]) * self.scale

    def section_length(self, name: str) -> float:
        """Axis length of section ``name`` (joint to joint, or joint to the free end), metres."""
        kind = kind_of(name)
        H = self.stature
        return {
            "head": _F["head"] * H,
            "chest": (_F["neck"] - _F["chest"]) * H,
            "waist": _F["chest"] * H,
            "upper_arm": _F["upper_arm"] * H,
            "forearm": (_F["forearm"] + _F["hand"]) * H,
            "thigh": _F["thigh"] * H,
            "lower_leg": (_F["lower_leg"] + _F["foot_height"]) * H,
        }[kind]

    def root_offset(self, joint: str) -> np.ndarray:
        """(3,) position of a limb root joint (``shoulder_l``, ``hip_r``...) in the model frame, metres."""
        side = 1.0 if joint.endswith("_l") else -1.0
        H = self.stature
        if joint.startswith("shoulder"):
            return np.array([side * _F["shoulder_x"], 0.0, _F["shoulder_z"]]) * H
        return np.array([side * _F["hip_x"], 0.0, _F["hip_z"]]) * H

    def limb_lengths(self, distal: str) -> float:
        """Total length of a limb chain from its root joint to its free end, metres."""
        if distal.startswith("forearm"):
            return (_F["upper_arm"] + _F["forearm"] + _F["hand"]) * self.stature
        return (_F["thigh"] + _F["lower_leg"] + _F["foot_height"]) * self.stature

    def end_joint_fraction(self, distal: str) -> float:
        """Where the wrist (ankle) lies along the forearm (lower leg) section, as a fraction of it."""
        if distal.startswith("forearm"):
            return _F["forearm"] / (_F["forearm"] + _F["hand"])
        return _F["lower_leg"] / (_F["lower_leg"] + _F["foot_height"])


def kind_of(name: str) -> str:
    """Section kind without side: ``upper_arm_l`` -> ``upper_arm``."""
    return name[:-2] if name.endswith(("_l", "_r")) else name


def standard_body(stature: float = STATURE) -> StandardBody:
    """The standard model scaled to ``stature`` metres."""
    if not 0.3 < stature < 3.0:
        raise ValueError(f"stature {stature} m is not a human stature")
    return StandardBody(float(stature))
