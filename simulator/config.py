"""Scanner geometry and imperfections: one frozen `ScannerConfig`, its `Head`s, and named presets.

Frame: metres, +z up, the subject faces -y, the subject's left is +x. The scanner's vertical axis
passes through the body's bounding-box centre (x, y) unless ``center_on_body`` is False, then through
the origin; head heights are above the floor (z = 0).

Each head is a camera plus a slit laser. With the ``parallel`` projection (paper section 4.1, the
synthetic set-up) every camera ray runs along the optical axis and every laser ray along one laser
direction; with ``perspective`` the camera is a pinhole at ``camera_distance`` from the scanner axis
and the laser sheet fans out from a point source displaced from the camera by the triangulation
baseline (swept over the body by a mirror, so that every point in the field can be lit).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass, field

from bodyscan._params import check_fields

from . import ScanError

PROJECTIONS = ("parallel", "perspective")


def _set_number(obj, name: str, what: str) -> None:
    """Store field ``name`` of a frozen dataclass as a finite Python float, or raise `ScanError`."""
    value = getattr(obj, name)
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        raise ScanError(f"{what} must be a finite number, got {value!r}")
    object.__setattr__(obj, name, float(value))


@dataclass(frozen=True)
class Head:
    """One camera with its slit laser, placed around the scanner's vertical axis.

    Attributes
    ----------
    name : str
        Label of the head (shown in previews and metadata).
    azimuth_deg : float
        Where the camera stands around the scanner axis, degrees, counter-clockwise seen from above:
        0 = in front of the subject (at -y, looking +y), 90 = at the subject's left (+x),
        180 = behind (at +y, looking -y).
    height : float
        Height of the optical axis where it crosses the scanner axis, metres above the floor.
    tilt_deg : float
        Elevation of the optical axis, degrees (positive looks up). 0 = horizontal.
    field_width, field_height : float
        Size of the camera's image on the plane through the scanner axis perpendicular to the
        optical axis, metres. Parts of the body outside it are not measured (with a warning).
    laser_roll_deg : float
        On which side of the camera the laser lies, degrees about the optical axis: 0 = above
        (the angle lies in the vertical plane; the laser line travels along the body as in tower
        scanners), 180 = below, 90 = to the camera's right, 270 = to its left.
    """

    name: str = field(default="front", metadata={"help": "label of the head", "unit": "", "range": None})
    azimuth_deg: float = field(default=0.0,
        metadata={"help": "where the camera stands around the axis, counter-clockwise from the front (180 = behind)", "unit": "deg", "range": (-360, 360)})
    height: float = field(default=1.1,
        metadata={"help": "height of the optical axis at the scanner axis", "unit": "m", "range": (-10, 10)})
    tilt_deg: float = field(default=0.0,
        metadata={"help": "elevation of the optical axis", "unit": "deg", "range": (-89, 89)})
    field_width: float = field(default=2.6,
        metadata={"help": "image width at the scanner axis", "unit": "m", "range": (0.001, 100)})
    field_height: float = field(default=2.6,
        metadata={"help": "image height at the scanner axis", "unit": "m", "range": (0.001, 100)})
    laser_roll_deg: float = field(default=0.0,
        metadata={"help": "laser side about the optical axis: 0 above, 180 below, 90 right, 270 left", "unit": "deg", "range": (-360, 360)})

    def __post_init__(self):
        object.__setattr__(self, "name", str(self.name))
        try:
            check_fields(self, ScanError)
        except ScanError as exc:
            raise ScanError(f"head {self.name!r}: {exc}") from None
        for f in ("azimuth_deg", "height", "tilt_deg", "field_width", "field_height", "laser_roll_deg"):
            _set_number(self, f, f"head {self.name!r}: {f}")
        if self.field_width <= 0 or self.field_height <= 0:
            raise ScanError(f"head {self.name!r}: field_width and field_height must be positive metres")
        if not -89.0 <= self.tilt_deg <= 89.0:
            raise ScanError(f"head {self.name!r}: tilt_deg must be within [-89, 89] degrees")


def head_layout(name: str = "front_rear") -> tuple[Head, ...]:
    """Named head arrangements.

    Parameters
    ----------
    name : {'front_rear', 'two_towers', 'four_towers', 'front'}
        ``front_rear``: one head in front and one behind, each seeing the whole body (the paper).
        ``two_towers``: a tower in front and one behind, each with two heads (upper one centred at
        1.55 m, lower one at 0.6 m, 1.4 m tall fields overlapping by 0.45 m); the lasers sit between
        the two heads of a tower (below the upper head, above the lower one), as in tower scanners.
        ``four_towers``: the same two-head towers at azimuths 45, 135, 225 and 315 degrees
        (8 heads), closer to commercial whole-body scanners. ``front``: the front head alone.

    Returns
    -------
    heads : tuple of Head
    """
    def tower(label, az):
        return (Head(f"{label}_upper", az, 1.55, 0.0, 2.6, 1.4, 180.0),
                Head(f"{label}_lower", az, 0.6, 0.0, 2.6, 1.4, 0.0))

    if name == "front_rear":
        return (Head("front", 0.0), Head("rear", 180.0))
    if name == "front":
        return (Head("front", 0.0),)
    if name == "two_towers":
        return tower("front", 0.0) + tower("rear", 180.0)
    if name == "four_towers":
        return sum((tower(lab, az) for lab, az in (("front_left", 45.0), ("rear_left", 135.0),
                                                  ("rear_right", 225.0), ("front_right", 315.0))), ())
    raise ScanError(f"unknown head layout {name!r} (use one of {', '.join(HEAD_LAYOUTS)})")


HEAD_LAYOUTS = ("front_rear", "two_towers", "four_towers", "front")


@dataclass(frozen=True)
class ScannerConfig:
    """Everything that defines a simulated scan. Defaults are the paper's synthetic set-up.

    Attributes
    ----------
    projection : {'parallel', 'perspective'}
        ``parallel``: camera rays along the optical axis, laser rays along one direction
        (paper 4.1). ``perspective``: pinhole camera and point laser source (a real scanner).
    laser_angle_deg : float
        Angle between the laser direction and the camera's optical axis, degrees; the paper uses
        k * 180 / 12 for k = 1, 2, 3 (see `k`). For ``perspective`` it is the angle at the point
        where the optical axis crosses the scanner axis, which fixes the baseline (`baseline`).
    resolution : float
        Sample spacing on the body (pixel pitch on the plane through the scanner axis), metres.
    heads : tuple of Head
        The cameras and their lasers (see `head_layout`).
    camera_distance : float
        ``perspective`` only: distance from each pinhole to the scanner axis, metres.
    noise_sigma : float
        Standard deviation of Gaussian range noise along the camera ray, metres.
    outlier_fraction : float
        Fraction of each head's points moved along their camera ray by a uniform offset in
        [-outlier_spread, outlier_spread] (stray triangulations).
    outlier_spread : float
        Largest outlier offset, metres.
    misalign_deg : float
        Per-head rigid misalignment: each head's points are rotated by exactly this angle about a
        random axis through the scanner centre (at half the body's height), degrees.
    misalign_mm : float
        Per-head rigid misalignment: then translated by exactly this distance in a random
        direction, millimetres.
    max_incidence_deg : float
        A point is measured only when both the camera ray and the laser ray meet the surface within
        this angle of its normal, degrees. 90 keeps every lit, visible point (the paper's rule).
    center_on_body : bool
        Put the scanner axis through the body's bounding-box centre (x, y); otherwise through the
        origin.
    seed : int
        Seed of every random choice (noise, outliers, misalignment).
    """

    projection: str = field(default="parallel",  # paper 4.1: synthetic data, cameras front and rear
        metadata={"help": "camera and laser model: parallel (paper) or perspective", "unit": "", "range": None})
    laser_angle_deg: float = field(default=15.0,  # paper 4.1: k * pi / 12, k = 1
        metadata={"help": "laser angle from the camera's optical axis (paper: k * 15)", "unit": "deg", "range": (-89.9, 89.9)})
    resolution: float = field(default=0.010,  # paper 4.1: about 10 mm on the body surface
        metadata={"help": "sample spacing on the body", "unit": "m", "range": (0.0001, 1)})
    heads: tuple = field(default_factory=lambda: head_layout("front_rear"),  # paper 4.1
        metadata={"help": "cameras with lasers: a layout name (front_rear, two_towers, four_towers, front) or a list of heads", "unit": "", "range": None})
    camera_distance: float = field(default=2.0,  # not in the paper (a typical booth)
        metadata={"help": "perspective: pinhole distance from the scanner axis", "unit": "m", "range": (0.01, 1000)})
    noise_sigma: float = field(default=0.0,  # paper 4.3: the real scanner had 1.0 mm error
        metadata={"help": "standard deviation of range noise along the camera ray", "unit": "m", "range": (0, 1)})
    outlier_fraction: float = field(default=0.0,  # paper 4.3 mentions noise removed by hand; off
        metadata={"help": "fraction of each head's points moved along their ray", "unit": "", "range": (0, 1)})
    outlier_spread: float = field(default=0.05,
        metadata={"help": "largest outlier offset", "unit": "m", "range": (0, 10)})
    misalign_deg: float = field(default=0.0,  # paper 5: camera overlap/shift left open; off
        metadata={"help": "per-head rotation about a random axis", "unit": "deg", "range": (0, 180)})
    misalign_mm: float = field(default=0.0,
        metadata={"help": "per-head shift in a random direction", "unit": "mm", "range": (0, 10000)})
    max_incidence_deg: float = field(default=90.0,  # paper: visible and lit, nothing more
        metadata={"help": "drop points seen or lit more obliquely than this from the normal (90 keeps all)", "unit": "deg", "range": (0.01, 90)})
    center_on_body: bool = field(default=True,
        metadata={"help": "scanner axis through the body's centre (else through the origin)", "unit": "", "range": None})
    seed: int = field(default=0,
        metadata={"help": "seed of noise, outliers and misalignment", "unit": "", "range": (0, None)})

    def __post_init__(self):
        if self.projection not in PROJECTIONS:
            raise ScanError(f"projection must be one of {', '.join(PROJECTIONS)}, got {self.projection!r}")
        heads = head_layout(self.heads) if isinstance(self.heads, str) else self.heads
        if not isinstance(heads, (list, tuple)):
            raise ScanError(f"heads must be a layout name ({', '.join(HEAD_LAYOUTS)}) or a list of heads, "
                            f"got {heads!r}")
        heads = tuple(_head(h) for h in heads)
        if not heads or not all(isinstance(h, Head) for h in heads):
            raise ScanError("heads must be a non-empty sequence of simulator.Head")
        if len({h.name for h in heads}) != len(heads):
            raise ScanError("head names must be distinct")
        if len(heads) > 255:
            raise ScanError("at most 255 heads")
        object.__setattr__(self, "heads", heads)
        check_fields(self, ScanError)
        for name in ("laser_angle_deg", "resolution", "camera_distance", "noise_sigma", "outlier_fraction",
                     "outlier_spread", "misalign_deg", "misalign_mm", "max_incidence_deg"):
            _set_number(self, name, f"scanner {name}")
        if not isinstance(self.seed, numbers.Integral) or isinstance(self.seed, bool) or self.seed < 0:
            raise ScanError(f"seed must be a non-negative integer, got {self.seed!r}")
        object.__setattr__(self, "seed", int(self.seed))
        checks = (
            ("laser_angle_deg", -89.9 < self.laser_angle_deg < 89.9, "within (-90, 90) degrees"),
            ("resolution", self.resolution > 0, "positive metres"),
            ("camera_distance", self.camera_distance > 0, "positive metres"),
            ("noise_sigma", self.noise_sigma >= 0, "zero or positive metres"),
            ("outlier_fraction", 0 <= self.outlier_fraction <= 1, "within [0, 1]"),
            ("outlier_spread", self.outlier_spread >= 0, "zero or positive metres"),
            ("misalign_deg", self.misalign_deg >= 0, "zero or positive degrees"),
            ("misalign_mm", self.misalign_mm >= 0, "zero or positive millimetres"),
            ("max_incidence_deg", 0 < self.max_incidence_deg <= 90, "within (0, 90] degrees"),
        )
        for name, ok, what in checks:
            if not ok:
                raise ScanError(f"scanner {name} must be {what}, got {getattr(self, name)!r}")
        if self.resolution < 1e-4:
            raise ScanError(f"scanner resolution {self.resolution} m is below 0.1 mm; give metres")

    @property
    def k(self) -> float:
        """The paper's laser-angle index: ``laser_angle_deg / 15``."""
        return self.laser_angle_deg / 15.0

    @property
    def baseline(self) -> float:
        """``perspective``: distance from camera to laser source, metres (D * tan(angle))."""
        return self.camera_distance * math.tan(math.radians(self.laser_angle_deg))

    def replace(self, **changes) -> "ScannerConfig":
        """A copy with some fields changed; ``k=`` sets ``laser_angle_deg = 15 * k``."""
        return dataclasses.replace(self, **_resolve_k(changes))

    def to_dict(self) -> dict:
        """Plain JSON-able dict of every field (heads as a list of dicts)."""
        d = dataclasses.asdict(self)
        d["heads"] = [dataclasses.asdict(h) for h in self.heads]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ScannerConfig":
        """Inverse of `to_dict`; unknown keys raise `ScanError`."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ScanError(f"unknown scanner parameter(s): {', '.join(unknown)} "
                            f"(known: {', '.join(sorted(names))})")
        d = dict(d)
        if "heads" in d:
            d["heads"] = tuple(Head(**h) if isinstance(h, dict) else h for h in d["heads"])
        return cls(**d)


def _head(h) -> Head:
    """A `Head` from a Head or a dict of its fields; anything else raises `ScanError`."""
    if isinstance(h, Head):
        return h
    if not isinstance(h, dict):
        raise ScanError(f"heads: each head is a mapping of Head fields, got {h!r}")
    known = {f.name for f in dataclasses.fields(Head)}
    unknown = sorted(set(h) - known)
    if unknown:
        raise ScanError(f"heads: unknown head field(s) {', '.join(map(str, unknown))} "
                        f"(known: {', '.join(sorted(known))})")
    return Head(**h)


def _resolve_k(changes: dict) -> dict:
    changes = dict(changes)
    if "k" in changes:
        k = changes.pop("k")
        if k is not None:
            try:
                k = float(k)
            except (TypeError, ValueError):
                raise ScanError(f"k={k!r}: expected a number (the laser angle in units of 15 degrees)") from None
            changes["laser_angle_deg"] = 15.0 * k
    return changes


#: Named starting points; `preset` returns them with changes applied.
PRESETS = {
    # paper 4.1: the synthetic data
    "paper": ScannerConfig(),
    # paper 4.3: the real scanner, 2 mm resolution and 1 mm error
    "scanner": ScannerConfig(projection="perspective", resolution=0.002, noise_sigma=0.001),
}


def preset(name: str = "paper", **changes) -> ScannerConfig:
    """The preset ``name`` ('paper' or 'scanner') with ``changes`` (field=value, or ``k=``)."""
    try:
        base = PRESETS[name]
    except KeyError:
        raise ScanError(f"unknown scanner preset {name!r} (use one of {', '.join(PRESETS)})") from None
    return base.replace(**changes) if changes else base
