"""Shapes of people and of two-wheelers with or without a rider as cuboid parts; see
shapes.py for the frame and the builder.

A figure is a `Pose` (joints in the object's x-z plane) dressed in parts: limbs at an
angle are two boxes stepping along the bone, so a walker's legs and swinging arms and a
rider's leaning back read as such from the side. Proportions of adults follow Drillis and
Contini's segment lengths as fractions of the stature h (thigh 0.245, shank 0.246, upper
arm 0.186, forearm 0.146, foot 0.152, hip 0.53, ankle 0.039; Winter, Biomechanics and Motor
Control of Human Movement, table 4.1); children (h < 1.45 m) keep a larger head (0.16 h)
and a shorter leg (0.47 h).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from sianms_cli.synth.appearance import BACKPACK_BAG, BALD, BEANIE, CAP, DRESS, FULL_FACE_HELMET, HANDBAG, \
    HARD_HAT, HI_VIS_VEST, LOGO_BAND, LONG_HAIR, NO_HEADWEAR, OPEN_HELMET, OPEN_JACKET, PONYTAIL, SHOPPING_BAG, \
    SHORTS, SHOULDER_BAG_LEFT, SHOULDER_BAG_RIGHT, SKIRT, STRIPES, Appearance
from sianms_cli.synth.shapes import CLOTH, HAIR, HEADLIGHT, METAL, PAINT, PAINT2, REFLECTOR, SKIN, TAILLIGHT, \
    TRIM, TYRE, Builder, ring

CHILD_HEIGHT = 1.45
"""Statures (m) below this are drawn with a child's proportions."""
SIDES = (1.0, -1.0)
"""Limb rows of a `Pose`: row 0 is the left limb (+y), row 1 the right one (-y)."""

_ANKLE, _FOOT, _UPPER_ARM, _FOREARM = 0.039, 0.152, 0.186, 0.146
_LEG_HALF, _ARM_HALF = 0.065, 0.045
# How far each headwear reaches above the crown (m): the body is built that much shorter
# so the figure keeps its stature inside the box.
_HEADWEAR_RISE = {NO_HEADWEAR: 0.0, CAP: 0.015, BEANIE: 0.025, HARD_HAT: 0.05, OPEN_HELMET: 0.04,
                  FULL_FACE_HELMET: 0.03}
_WHITE_BAG = np.array([0.75, 0.74, 0.70], np.float32)
_GRIP_INSET = 0.06


@dataclass(frozen=True)
class Pose:
    """Joints of one figure in the object frame, metres: points are (x, z), x forward, z up.

    pelvis, shoulder (2,): the hip joints' and the shoulder joints' midpoints; neck (2,) the
    base of the neck (top of the trunk); head (2,) the head's centre; knee, ankle, toe,
    elbow, wrist (2,2): row i is the limb on side SIDES[i]; head_h: head height; hip_y,
    arm_y: half spacing of the legs and of the arms along y; torso_hw, torso_hx: half width
    and half depth of the trunk.
    """

    pelvis: np.ndarray
    shoulder: np.ndarray
    neck: np.ndarray
    head: np.ndarray
    knee: np.ndarray
    ankle: np.ndarray
    toe: np.ndarray
    elbow: np.ndarray
    wrist: np.ndarray
    head_h: float
    hip_y: float
    arm_y: float
    torso_hw: float
    torso_hx: float


def _bone(joint, angle: float, length: float) -> np.ndarray:
    """End of a bone of `length` hanging from `joint` (x, z), swung `angle` rad forward of down."""
    return np.asarray(joint, float) + length * np.array([np.sin(angle), -np.cos(angle)])


def _reach(root, target, a: float, b: float, bend: float) -> np.ndarray:
    """Middle joint of a two-bone chain root-(a)-joint-(b)-target in the x-z plane (knee,
    elbow); bend +1 puts the joint on the counter-clockwise side of the root-target line
    seen from +y (a knee ahead), -1 on the other (an elbow below). A target out of reach
    straightens the chain towards it."""
    root, target = np.asarray(root, float), np.asarray(target, float)
    d = target - root
    dist = float(np.clip(np.hypot(*d), abs(a - b) + 1e-6, a + b - 1e-6))
    opening = np.arccos(np.clip((a * a + dist * dist - b * b) / (2 * a * dist), -1.0, 1.0))
    angle = np.arctan2(d[1], d[0]) + bend * opening
    return root + a * np.array([np.cos(angle), np.sin(angle)])


def _proportions(h: float) -> tuple[float, float, float, float]:
    """(head height, hip height, neck height, torso half width) of a standing figure of stature h."""
    child = h < CHILD_HEIGHT
    head_h = (0.16 if child else 0.13) * h
    hip = (0.47 if child else 0.52) * h
    return head_h, hip, h - head_h - 0.03 * h, 0.15 if child else 0.19


def walking_pose(h: float, span: float, phase: float) -> Pose:
    """A walker of stature h (m) in mid-stride, its feet reaching `span` metres along x from
    the back heel to the front toe (the annotation box's length), at gait `phase` in [0, 1):
    the left leg is forward in the first half of the cycle, the right one in the second;
    through each half the back knee bends towards toe-off. The arms swing opposite to the
    legs. The lower foot stands on z = 0."""
    head_h, hip_z, neck_z, torso_hw = _proportions(h)
    front = 0 if phase < 0.5 else 1
    late = 2.0 * (phase % 0.5)
    knee_bend = np.where(np.arange(2) == front, 0.05 + 0.1 * (1 - late), 0.15 + 0.35 * late)
    swing = np.where(np.arange(2) == front, 1.0, -0.8)
    ankle_h, foot = _ANKLE * h, _FOOT * h

    def legs(theta: float):
        thigh_angle = swing * theta
        shin_angle = thigh_angle - knee_bend
        # Bones long enough that the lower ankle is at ankle height with the hip at hip height.
        bone = (hip_z - ankle_h) / float(np.max(np.cos(thigh_angle) + np.cos(shin_angle)))
        knee = np.array([_bone((0.0, hip_z), a, bone) for a in thigh_angle])
        ankle = np.array([_bone(k, a, bone) for k, a in zip(knee, shin_angle)])
        return knee, ankle, ankle[:, 0].max() + 0.7 * foot - (ankle[:, 0].min() - 0.3 * foot)

    lo, hi = 0.05, 0.5
    for _ in range(24):  # the span grows with the stride angle: bisect for the box's length
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if legs(mid)[2] < span else (lo, mid)
    theta = 0.5 * (lo + hi)
    knee, ankle, _ = legs(theta)
    toe = ankle + np.array([0.7 * foot, 0.0])
    shoulder = np.array([0.0, neck_z - 0.03 * h])
    upper_angle = -swing * 0.6 * theta
    elbow = np.array([_bone(shoulder, a, _UPPER_ARM * h) for a in upper_angle])
    wrist = np.array([_bone(e, a + 0.25 + 0.2 * late, _FOREARM * h) for e, a in zip(elbow, upper_angle)])
    torso_hx = 0.09 if h < CHILD_HEIGHT else 0.11
    return Pose(np.array([0.0, hip_z]), shoulder, np.array([0.0, neck_z]), np.array([0.0, h - head_h / 2]),
                knee, ankle, toe, elbow, wrist, head_h, 0.09, torso_hw + _ARM_HALF, torso_hw, torso_hx)


def riding_pose(h: float, hip, grips, feet, hip_y: float) -> Pose:
    """A rider of stature h seated with the hip joints at `hip` (x, z), leaning forward just
    enough for the wrists to reach the handlebar grips (x, z) with the elbows a little bent,
    the balls of the feet on `feet` (2,2) (pedals or footpegs of the left and right side),
    the knees ahead and the elbows below. Where a foot target is out of the leg's reach
    (a short rider on a tall frame, the pedal at its lowest) the hip sinks into the saddle
    until it is within reach, as a rider sits lower to pedal."""
    head_h, hip_n, neck_n, torso_hw = _proportions(h)
    hip, grips, feet = np.asarray(hip, float).copy(), np.asarray(grips, float), np.asarray(feet, float)
    ankle = feet + np.array([-0.25 * _FOOT * h, _ANKLE * h])
    bone = (hip_n - _ANKLE * h) / 2
    reach = 0.98 * 2 * bone
    dx = np.minimum(np.abs(ankle[:, 0] - hip[0]), reach)
    hip[1] = min(hip[1], float(np.min(ankle[:, 1] + np.sqrt(reach**2 - dx**2))))
    torso = neck_n - hip_n
    arm = (_UPPER_ARM + _FOREARM) * h

    def shoulder(lean: float) -> np.ndarray:
        return hip + (torso - 0.03 * h) * np.array([np.sin(lean), np.cos(lean)])

    lo, hi = 0.0, 1.3
    for _ in range(24):  # leaning forward brings the shoulders nearer the grips
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.hypot(*(grips - shoulder(mid))) > 0.9 * arm else (lo, mid)
    lean = 0.5 * (lo + hi)
    neck = hip + torso * np.array([np.sin(lean), np.cos(lean)])
    head = neck + (0.03 * h + head_h / 2) * np.array([np.sin(0.4 * lean), np.cos(0.4 * lean)])
    knee = np.array([_reach(hip, a, bone, bone, +1.0) for a in ankle])
    toe = ankle + np.array([0.7 * _FOOT * h, 0.0])
    elbow = np.array([_reach(shoulder(lean), grips, _UPPER_ARM * h, _FOREARM * h, -1.0)] * 2)
    wrist = np.array([grips, grips])
    return Pose(hip, shoulder(lean), neck, head, knee, ankle, toe, elbow, wrist, head_h, hip_y,
                torso_hw + _ARM_HALF, torso_hw, 0.11)


def _segment(b: Builder, p, q, y: float, half_y: float, half_t: float, material: int, albedo,
             pieces: int = 2) -> None:
    """A bone from p to q (x, z) of half thickness half_t, as `pieces` axis-aligned boxes
    stepping along it (one box when it is near vertical or horizontal)."""
    p, q = np.asarray(p, float), np.asarray(q, float)
    d = q - p
    unit = d / max(float(np.hypot(*d)), 1e-9)
    pad = half_t * np.abs(unit[::-1])
    if min(abs(unit[0]), abs(unit[1])) < 0.15:
        pieces = 1
    for k in range(pieces):
        a, c = p + d * k / pieces, p + d * (k + 1) / pieces
        lo, hi = np.minimum(a, c) - pad, np.maximum(a, c) + pad
        b.add((lo[0], y - half_y, lo[1]), (hi[0], y + half_y, hi[1]), material, albedo)


def _legs(b: Builder, pose: Pose, h: float, app: Appearance) -> None:
    """Thighs, shins and shoes; shorts and skirts bare the shins (and the knees)."""
    bare = app.legwear in (SHORTS, SKIRT, DRESS)
    for i, side in enumerate(SIDES):
        y = side * pose.hip_y
        knee_mid = 0.5 * (pose.pelvis + pose.knee[i])
        _segment(b, pose.pelvis, knee_mid, y, _LEG_HALF, _LEG_HALF, CLOTH, app.bottom, 1)
        _segment(b, knee_mid, pose.knee[i], y, _LEG_HALF, _LEG_HALF, SKIN if bare else CLOTH,
                 app.skin if bare else app.bottom, 1)
        _segment(b, pose.knee[i], pose.ankle[i], y, 0.055, 0.055, SKIN if bare else CLOTH,
                 app.skin if bare else app.bottom)
        heel = pose.ankle[i] - np.array([0.3 * _FOOT * h, _ANKLE * h])
        b.add((heel[0], y - 0.05, heel[1]), (pose.toe[i][0], y + 0.05, pose.ankle[i][1] + 0.02), CLOTH,
              app.shoes)
    if app.legwear in (SKIRT, DRESS):
        hem = 0.5 * (pose.pelvis + pose.knee.mean(axis=0))
        flare = np.abs(pose.knee[:, 0] - pose.pelvis[0]).max() * 0.5 + pose.torso_hx
        b.add((pose.pelvis[0] - flare, -pose.torso_hw, hem[1]),
              (pose.pelvis[0] + flare, pose.torso_hw, pose.pelvis[1] + 0.04 * h), CLOTH, app.bottom)


def _torso(b: Builder, pose: Pose, h: float, app: Appearance, riding: bool) -> None:
    """Pelvis, trunk (two boxes along a rider's lean) and the top's pattern on its faces."""
    hx, hw = pose.torso_hx, pose.torso_hw
    b.add((pose.pelvis[0] - hx, -pose.hip_y - _LEG_HALF, pose.pelvis[1] - 0.03 * h),
          (pose.pelvis[0] + hx, pose.hip_y + _LEG_HALF, pose.pelvis[1] + 0.05 * h), CLOTH, app.bottom)
    waist = pose.pelvis + np.array([0.0, 0.05 * h])
    jacket = app.top_style in (OPEN_JACKET, HI_VIS_VEST)
    _segment(b, waist, pose.neck, 0.0, hw, hx, CLOTH, app.accent if jacket else app.top, 2 if riding else 1)
    if riding:
        return
    front, z0, z1 = pose.torso_hx, waist[1], pose.neck[1]
    skin = 0.006  # thin parts proud of the torso's faces
    if app.top_style == OPEN_JACKET:
        b.add((front, -0.3 * hw, z0 + 0.02), (front + skin, 0.3 * hw, z1 - 0.01), CLOTH, app.top)
    elif app.top_style == STRIPES:
        for k in range(3):
            zc = z0 + (z1 - z0) * (0.25 + 0.22 * k)
            b.add((-hx - skin, -hw - skin, zc - 0.02), (hx + skin, hw + skin, zc + 0.02), CLOTH, app.accent)
    elif app.top_style == LOGO_BAND:
        zc = z0 + 0.68 * (z1 - z0)
        b.add((front, -0.7 * hw, zc - 0.045), (front + skin, 0.7 * hw, zc + 0.045), CLOTH, app.accent)
    elif app.top_style == HI_VIS_VEST:
        for frac in (0.3, 0.6):
            zc = z0 + frac * (z1 - z0)
            b.add((-hx - skin, -hw - skin, zc - 0.025), (hx + skin, hw + skin, zc + 0.025), REFLECTOR)


def _arms(b: Builder, pose: Pose, app: Appearance) -> None:
    """Upper arms and forearms (bare below a short sleeve) and hands."""
    sleeve = app.accent if app.top_style == OPEN_JACKET else app.top
    short = app.variant % 2 == 1 and app.top_style != OPEN_JACKET
    for i, side in enumerate(SIDES):
        y = side * pose.arm_y
        _segment(b, pose.shoulder, pose.elbow[i], y, _ARM_HALF, _ARM_HALF, CLOTH, sleeve, 1)
        _segment(b, pose.elbow[i], pose.wrist[i], y, 0.04, 0.04, SKIN if short else CLOTH,
                 app.skin if short else sleeve)
        b.add_center((pose.wrist[i][0], y, pose.wrist[i][1]), (0.04, 0.035, 0.045), SKIN, app.skin)


def _head(b: Builder, pose: Pose, app: Appearance) -> None:
    """Neck, head, hair and headwear; hard hats and helmets in the `secondary` colour."""
    helmet = app.secondary
    x, zc = pose.head
    half = pose.head_h / 2
    top = zc + half
    b.add((pose.neck[0] - 0.05, -0.05, pose.neck[1] - 0.02), (pose.neck[0] + 0.05, 0.05, zc - half + 0.02),
          SKIN, app.skin)
    if app.headwear != FULL_FACE_HELMET:
        b.add_center((x, 0.0, zc), (0.095, 0.08, half), SKIN, app.skin)
    if app.headwear in (NO_HEADWEAR, CAP) and app.hair_style != BALD:
        b.add((x - 0.11, -0.095, top - 0.45 * pose.head_h), (x + 0.07, 0.095, top), HAIR, app.hair)
    if app.hair_style == LONG_HAIR and app.headwear != FULL_FACE_HELMET:
        b.add((x - 0.12, -0.09, zc - half - 0.06), (x - 0.06, 0.09, zc + 0.3 * half), HAIR, app.hair)
    elif app.hair_style == PONYTAIL and app.headwear != FULL_FACE_HELMET:
        b.add((x - 0.16, -0.03, zc - 0.5 * half), (x - 0.1, 0.03, zc + 0.3 * half), HAIR, app.hair)
    rise = _HEADWEAR_RISE[app.headwear]
    if app.headwear == CAP:
        b.add((x - 0.105, -0.09, top - 0.3 * pose.head_h), (x + 0.08, 0.09, top + rise), CLOTH, app.accent)
        b.add((x + 0.08, -0.07, top - 0.3 * pose.head_h), (x + 0.16, 0.07, top - 0.27 * pose.head_h), CLOTH,
              app.accent)
    elif app.headwear == BEANIE:
        b.add((x - 0.105, -0.09, top - 0.4 * pose.head_h), (x + 0.1, 0.09, top + rise), CLOTH, app.accent)
    elif app.headwear == HARD_HAT:
        b.add((x - 0.12, -0.11, top - 0.25 * pose.head_h), (x + 0.12, 0.11, top + rise), PAINT2, helmet)
        b.add((x + 0.12, -0.09, top - 0.25 * pose.head_h), (x + 0.17, 0.09, top - 0.2 * pose.head_h), PAINT2,
              helmet)
    elif app.headwear == OPEN_HELMET:
        b.add((x - 0.13, -0.1, top - 0.35 * pose.head_h), (x + 0.11, 0.1, top + rise), PAINT2, helmet)
    elif app.headwear == FULL_FACE_HELMET:
        b.add((x - 0.12, -0.11, zc - half - 0.02), (x + 0.12, 0.11, top + rise), PAINT2, helmet)
        b.add((x + 0.12, -0.075, zc - 0.1 * half), (x + 0.126, 0.075, zc + 0.45 * half), TRIM)


def _bag(b: Builder, pose: Pose, h: float, app: Appearance) -> None:
    """A backpack behind the shoulders, a bag on one hip with its strap over that shoulder,
    or a handbag or shopping bag hanging from the left hand."""
    hx, hw = pose.torso_hx, pose.torso_hw
    if app.bag == BACKPACK_BAG:
        b.add((-hx - 0.16, -0.15, pose.pelvis[1] + 0.1 * h), (-hx, 0.15, pose.neck[1] - 0.03), PAINT2,
              app.secondary)
    elif app.bag in (SHOULDER_BAG_LEFT, SHOULDER_BAG_RIGHT):
        side = 1.0 if app.bag == SHOULDER_BAG_LEFT else -1.0
        y_in, y_out = side * 0.7 * hw, side * (hw + 0.09)
        z = pose.pelvis[1]
        b.add((-0.12, min(y_in, y_out), z - 0.06 * h), (0.1, max(y_in, y_out), z + 0.05 * h), CLOTH,
              app.accent)
        b.add((hx, side * 0.45 * hw - 0.02, z + 0.05 * h), (hx + 0.006, side * 0.45 * hw + 0.02,
              pose.neck[1]), CLOTH, app.accent)
    elif app.bag in (HANDBAG, SHOPPING_BAG):
        hand = pose.wrist[0]
        depth = 0.28 if app.bag == SHOPPING_BAG else 0.2
        colour = _WHITE_BAG if app.bag == SHOPPING_BAG else app.accent
        b.add((hand[0] - 0.13, pose.arm_y - 0.05, hand[1] - 0.04 - depth),
              (hand[0] + 0.13, pose.arm_y + 0.05, hand[1] - 0.04), CLOTH, colour)


def _raised(pose: Pose, dz: float) -> Pose:
    """The same pose moved dz metres up."""
    up = np.array([0.0, dz])
    return replace(pose, **{name: getattr(pose, name) + up for name in
                            ("pelvis", "shoulder", "neck", "head", "knee", "ankle", "toe", "elbow", "wrist")})


def _pedestrian(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    """A walker toward +x; the feet's reach along x is the box length (within what a stride
    allows), the arms' along y its width (within a few centimetres of the trunk)."""
    body = h - _HEADWEAR_RISE[app.headwear]
    pose = _raised(walking_pose(body, l, app.gait_phase), -h / 2)
    # Arms held up to 5 cm off the trunk where the box is wide, so that the box's width
    # comes from where the arms are rather than from stretching the trunk.
    gap = float(np.clip(w / 2 - pose.arm_y - _ARM_HALF, 0.0, 0.05))
    pose = replace(pose, arm_y=pose.arm_y + gap)
    _legs(b, pose, body, app)
    _torso(b, pose, body, app, riding=False)
    _arms(b, pose, app)
    _head(b, pose, app)
    _bag(b, pose, body, app)


@dataclass(frozen=True)
class CycleGeometry:
    """Key points of a two-wheeler in the object frame (x, z) metres, built for a box w x l x h.

    wheel_radius; axle: axle height; wheelbase; frame_top: top tube (tank) height; saddle
    (x, z) top of the saddle or seat; grips (x, z) handlebar grips; bottom_bracket (x, z) the
    crank axis (a motorcycle's footpeg centre); foot_rests (2,2) the left and right pedal or
    footpeg (x, z); foot_y: half spacing of the rider's legs along y.
    """

    wheel_radius: float
    axle: float
    wheelbase: float
    frame_top: float
    saddle: np.ndarray
    grips: np.ndarray
    bottom_bracket: np.ndarray
    foot_rests: np.ndarray
    foot_y: float


def cycle_geometry(l: float, h: float, motor: bool, phase: float) -> CycleGeometry:
    """Where the wheels, saddle, grips and pedals (footpegs) of a bicycle (motorcycle) of
    length l and box height h are; `phase` in [0, 1) turns the cranks."""
    r = 0.3 if motor else 0.34
    wheelbase = l - 2 * r
    axle = -h / 2 + r
    frame_top = axle + (0.55 if motor else 0.45)
    seat_x = -0.18 * wheelbase
    saddle = np.array([seat_x, frame_top + (0.0 if motor else 0.1)])
    grips = np.array([wheelbase / 2 - 0.1, frame_top + 0.175])
    if motor:
        bracket = np.array([seat_x + 0.12 * wheelbase, axle + 0.02])
        rests = np.array([bracket, bracket])
        return CycleGeometry(r, axle, wheelbase, frame_top, saddle, grips, bracket, rests, 0.2)
    bracket = np.array([seat_x + 0.1, axle - 0.03])
    crank = 2 * np.pi * phase + np.array([0.0, np.pi])
    rests = bracket + 0.17 * np.stack([np.cos(crank), np.sin(crank)], axis=1)
    return CycleGeometry(r, axle, wheelbase, frame_top, saddle, grips, bracket, rests, 0.1)


def _bicycle_frame(b: Builder, g: CycleGeometry, w: float, app: Appearance) -> None:
    """Diamond frame (top, down, seat tube; chain and seat stays), fork, bar, saddle, cranks."""
    rear, front = (-g.wheelbase / 2, g.axle), (g.wheelbase / 2, g.axle)
    cluster = (g.saddle[0], g.frame_top)
    head_top = (g.grips[0] + 0.02, g.frame_top + 0.05)
    head_low = (g.grips[0] + 0.0, g.frame_top - 0.12)
    bb = g.bottom_bracket
    for p, q, pieces in ((cluster, head_top, 1), (head_low, bb, 3), (cluster, bb, 1), (rear, bb, 1),
                         (cluster, rear, 2)):
        _segment(b, p, q, 0.0, 0.02, 0.02, PAINT, app.base, pieces)
    _segment(b, head_low, front, 0.0, 0.03, 0.018, METAL, None, 1)
    _segment(b, head_low, head_top, 0.0, 0.025, 0.025, PAINT, app.base, 1)
    b.add((head_top[0] - 0.02, -0.02, head_top[1]), (g.grips[0] + 0.02, 0.02, g.grips[1]), METAL)
    b.add((g.grips[0] - 0.025, -w / 2, g.grips[1] - 0.025), (g.grips[0] + 0.025, w / 2, g.grips[1] + 0.025), TRIM)
    b.add((g.saddle[0] - 0.015, -0.015, g.frame_top), (g.saddle[0] + 0.015, 0.015, g.saddle[1] - 0.04), METAL)
    b.add((g.saddle[0] - 0.11, -0.07, g.saddle[1] - 0.04), (g.saddle[0] + 0.12, 0.07, g.saddle[1]), TRIM)
    for i, side in enumerate(SIDES):
        _segment(b, bb, g.foot_rests[i], side * 0.05, 0.01, 0.015, METAL, None, 1)
        b.add_center((g.foot_rests[i][0], side * 0.09, g.foot_rests[i][1] - 0.0075), (0.05, 0.04, 0.0125), METAL)


def _motorcycle_body(b: Builder, g: CycleGeometry, w: float, app: Appearance) -> None:
    """Engine, tank, seat, tail, exhaust on the right, fork, bar, lights and footpegs."""
    wb, axle, top = g.wheelbase, g.axle, g.frame_top
    b.add((-0.3 * wb, -0.16, axle - 0.1), (0.3 * wb, 0.16, axle + 0.3), METAL)
    b.add((0.0, -0.17, axle + 0.3), (0.35 * wb, 0.17, top), PAINT, app.base)
    b.add((-0.45 * wb, -0.15, axle + 0.3), (0.0, 0.15, top - 0.08), TRIM)
    b.add((-wb / 2 - 0.1, -0.1, axle + 0.2), (-0.3 * wb, 0.1, axle + 0.35), PAINT, app.base)
    _segment(b, (0.1 * wb, axle - 0.05), (-0.45 * wb, axle + 0.1), -0.2, 0.04, 0.04, METAL, None, 2)
    _segment(b, (g.grips[0] + 0.05, top + 0.18), (wb / 2, axle), 0.0, 0.04, 0.025, METAL, None, 2)
    b.add((g.grips[0] - 0.03, -w / 2, g.grips[1] - 0.025), (g.grips[0] + 0.03, w / 2, g.grips[1] + 0.025), TRIM)
    b.add_center((wb / 2 + 0.05, 0.0, top), (0.03, 0.09, 0.06), HEADLIGHT)
    b.add_center((-wb / 2 - 0.11, 0.0, axle + 0.32), (0.01, 0.07, 0.04), TAILLIGHT)
    for side in SIDES:
        b.add_center((g.foot_rests[0][0], side * (0.2 + 0.04), g.foot_rests[0][1] - 0.01), (0.03, 0.04, 0.015),
                     METAL)


def _rider(b: Builder, g: CycleGeometry, h: float, app: Appearance) -> None:
    """A rider on the saddle, hands on the grips, the balls of the feet on the pedals or pegs."""
    z0 = -h / 2
    rider_h = float(np.clip(h - (g.saddle[1] - z0) + 0.47 * 1.75, 1.5, 1.9)) - _HEADWEAR_RISE[app.headwear]
    hip = g.saddle + np.array([0.02, 0.05 * rider_h])
    pose = riding_pose(rider_h, hip, g.grips, g.foot_rests, g.foot_y)
    _legs(b, pose, rider_h, app)
    _torso(b, pose, rider_h, app, riding=True)
    _arms(b, pose, app)
    _head(b, pose, app)


def _cycle(b: Builder, w: float, l: float, h: float, app: Appearance, motor: bool) -> None:
    g = cycle_geometry(l, h, motor, app.gait_phase)
    thick = 0.07 if motor else 0.025
    for x in (g.wheelbase / 2, -g.wheelbase / 2):
        ring(b, x, g.axle, g.wheel_radius, 0.06 if motor else 0.02, thick, TYRE)
    if motor:
        _motorcycle_body(b, g, w, app)
    else:
        _bicycle_frame(b, g, w, app)
    if app.rider:
        _rider(b, g, h, app)


BUILDERS = {
    "pedestrian": _pedestrian,
    "bicycle": lambda b, w, l, h, app: _cycle(b, w, l, h, app, motor=False),
    "motorcycle": lambda b, w, l, h, app: _cycle(b, w, l, h, app, motor=True),
}
"""Builders of people and two-wheelers: kind -> f(builder, w, l, h, appearance)."""
