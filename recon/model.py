"""Section geometry of the body model: elliptic columns with ellipsoidal caps, and their coordinates.

Each of the 11 body sections is one `SectionShape`: a column (a cylinder when both radii are equal,
an elliptic column otherwise) along an axis from ``start`` (the proximal joint) to ``end``, closed at
either end by a half-ellipsoid cap, or open (the column extends past that end: an extended arm whose
end the fit could not find, paper section 2.4).

The section coordinates of paper section 3 are ``(r, theta, h)``: ``h`` along the axis from ``start``
(metres), ``theta`` around the axis from ``frame_x`` (radians, [0, 2*pi)), and ``r`` the signed
distance from the model surface (metres, negative inside). ``r`` is measured along the ray from the
nearest axis point, which is the exact Euclidean distance for a cylinder with hemispherical caps and
a close approximation for elliptic columns (their radii differ by less than 2x here).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

#: The 11 body sections, in label order; the same order as ``poses.SECTIONS`` (recon reads no poses).
SECTIONS = (
    "head", "chest", "waist",
    "upper_arm_l", "upper_arm_r", "forearm_l", "forearm_r",
    "thigh_l", "thigh_r", "lower_leg_l", "lower_leg_r",
)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


@dataclass(frozen=True, eq=False)
class SectionShape:
    """One body section of the model.

    Attributes
    ----------
    name : str
        One of `SECTIONS`.
    start, end : (3,) float
        Axis end points, metres; ``start`` is the proximal joint.
    radii : (2,) float
        Semi-axes (a, b) of the cross-section, metres, along ``frame_x`` and along axis x frame_x.
    frame_x : (3,) float
        Unit vector perpendicular to the axis: direction of ``theta = 0`` and of radius ``a``.
    closed : (2,) bool
        Whether the start and end caps are closed; an open end extends the column instead.
    caps : (2,) float
        Height of the start and end caps along the axis, metres (a hemisphere has height = radius).
    """

    name: str
    start: np.ndarray
    end: np.ndarray
    radii: np.ndarray
    frame_x: np.ndarray
    closed: tuple = (True, True)
    caps: np.ndarray = field(default=None)

    def __post_init__(self):
        start = np.asarray(self.start, dtype=np.float64)
        end = np.asarray(self.end, dtype=np.float64)
        if not np.linalg.norm(end - start) > 0:
            raise ValueError(f"section {self.name}: start and end coincide")
        axis = _unit(end - start)
        fx = np.asarray(self.frame_x, dtype=np.float64)
        fx = fx - axis * (fx @ axis)  # keep frame_x exactly perpendicular to the axis
        if not np.linalg.norm(fx) > 1e-9:
            raise ValueError(f"section {self.name}: frame_x is parallel to the axis")
        radii = np.broadcast_to(np.asarray(self.radii, dtype=np.float64), (2,)).copy()
        caps = radii.mean() if self.caps is None else self.caps
        object.__setattr__(self, "start", start)
        object.__setattr__(self, "end", end)
        object.__setattr__(self, "frame_x", _unit(fx))
        object.__setattr__(self, "radii", radii)
        object.__setattr__(self, "closed", tuple(bool(c) for c in self.closed))
        object.__setattr__(self, "caps", np.broadcast_to(np.asarray(caps, dtype=np.float64), (2,)).copy())

    # -- derived geometry ---------------------------------------------------------------------
    @property
    def axis(self) -> np.ndarray:
        """(3,) unit vector from start to end."""
        return _unit(self.end - self.start)

    @property
    def length(self) -> float:
        """Axis length, metres."""
        return float(np.linalg.norm(self.end - self.start))

    @property
    def width(self) -> float:
        """Largest cross-section diameter, metres (2 * max radius): the paper's section width."""
        return float(2.0 * self.radii.max())

    @property
    def frame(self) -> np.ndarray:
        """(3, 3) rows: frame_x, frame_y = axis x frame_x, axis."""
        z = self.axis
        return np.stack([self.frame_x, np.cross(z, self.frame_x), z])

    @property
    def is_cylinder(self) -> bool:
        return bool(np.isclose(self.radii[0], self.radii[1]))

    def replace(self, **changes) -> "SectionShape":
        """A copy with some fields changed."""
        return replace(self, **changes)

    def moved(self, R: np.ndarray, t: np.ndarray) -> "SectionShape":
        """The section carried by the rigid motion ``p -> R @ p + t`` (R (3, 3) a rotation, t (3,))."""
        R = np.asarray(R, dtype=np.float64)
        return self.replace(start=R @ self.start + t, end=R @ self.end + t, frame_x=R @ self.frame_x)

    # -- coordinates --------------------------------------------------------------------------
    def local(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) coordinates of ``points`` (n, 3) in the section frame: x, y across, h along the axis."""
        return (np.asarray(points, dtype=np.float64) - self.start) @ self.frame.T

    def radius_at(self, theta: np.ndarray) -> np.ndarray:
        """(n,) radius of the cross-section ellipse at angle ``theta`` (n,), metres."""
        a, b = self.radii
        return a * b / np.hypot(b * np.cos(theta), a * np.sin(theta))

    def _scaled(self, points: np.ndarray):
        """Local ``x, y, h`` (n,), the axial excess ``e`` (n,) beyond a closed end, and ``s`` (n,):
        the point's distance from the axis in units of the surface's (1 on the surface)."""
        q = self.local(points)
        x, y, h = q[:, 0], q[:, 1], q[:, 2]
        # axial excess beyond a closed end (an open end extends the column)
        e = np.zeros_like(h)
        c = np.ones_like(h)
        if self.closed[0]:
            m = h < 0
            e[m], c[m] = h[m], self.caps[0]
        if self.closed[1]:
            m = h > self.length
            e[m], c[m] = h[m] - self.length, self.caps[1]
        a, b = self.radii
        s = np.sqrt((x / a) ** 2 + (y / b) ** 2 + (e / c) ** 2)
        return x, y, h, e, s

    def _signed(self, x, y, e, s) -> np.ndarray:
        norm = np.sqrt(x ** 2 + y ** 2 + e ** 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(s > 0, norm * (1.0 - 1.0 / s), -min(self.radii))

    def coords(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Section coordinates ``(r, theta, h)`` of ``points`` (n, 3).

        Returns
        -------
        r : (n,) float
            Signed distance from the model surface, metres (negative inside).
        theta : (n,) float
            Angle around the axis from ``frame_x``, radians in [0, 2*pi).
        h : (n,) float
            Position along the axis from ``start``, metres.
        """
        x, y, h, e, s = self._scaled(points)
        theta = np.mod(np.arctan2(y, x), 2 * np.pi)
        return self._signed(x, y, e, s), theta, h

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) unsigned distance from ``points`` (n, 3) to the model surface, metres."""
        x, y, _, e, s = self._scaled(points)
        return np.abs(self._signed(x, y, e, s))

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: ``points`` (n, 3) inside the model surface (``coords``' r < 0)."""
        return self._scaled(points)[-1] < 1.0

    def surface_points(self, n_theta: int = 24, n_h: int = 12) -> np.ndarray:
        """(m, 3) points on the column and closed caps, for drawing and tests."""
        t = np.linspace(0, 2 * np.pi, n_theta, endpoint=False)
        R = self.radius_at(t)
        h = np.linspace(0, self.length, n_h)
        fx, fy, z = self.frame
        col = (self.start + (R * np.cos(t))[None, :, None] * fx + (R * np.sin(t))[None, :, None] * fy
               + h[:, None, None] * z).reshape(-1, 3)
        parts = [col]
        phi = np.linspace(0, np.pi / 2, n_h // 2 + 1)[1:]  # polar angle from the cap's pole
        for end, (closed, cap, base, sign) in enumerate(zip(self.closed, self.caps, (self.start, self.end), (-1, 1))):
            if not closed:
                continue
            rr = np.sin(phi)[:, None] * R[None, :]
            hh = sign * cap * np.cos(phi)[:, None] * np.ones_like(R)[None, :]
            parts.append((base + (rr * np.cos(t))[..., None] * fx + (rr * np.sin(t))[..., None] * fy
                          + hh[..., None] * z).reshape(-1, 3))
        return np.concatenate(parts)

    def to_dict(self) -> dict:
        """JSON-ready description (lists of floats)."""
        return {
            "shape": "cylinder" if self.is_cylinder else "elliptic_column",
            "start": self.start.tolist(), "end": self.end.tolist(),
            "radii": self.radii.tolist(), "length": self.length,
            "frame_x": self.frame_x.tolist(), "closed": list(self.closed), "caps": self.caps.tolist(),
        }

    @classmethod
    def from_dict(cls, name: str, d: dict) -> "SectionShape":
        return cls(name=name, start=d["start"], end=d["end"], radii=d["radii"], frame_x=d["frame_x"],
                   closed=tuple(d["closed"]), caps=d["caps"])


def section_coords(sections: dict[str, SectionShape], points: np.ndarray):
    """Section coordinates of ``points`` (n, 3) for every section in ``SECTIONS`` order.

    Returns
    -------
    r, theta, h : (n, 11) float
        As `SectionShape.coords`; columns of sections absent from ``sections`` are NaN.
    """
    n = len(points)
    out = np.full((3, n, len(SECTIONS)), np.nan)
    for j, name in enumerate(SECTIONS):
        if name in sections:
            out[:, :, j] = sections[name].coords(points)
    return out[0], out[1], out[2]


#: Adjacent sections and the joint between them: {(proximal, distal): joint name}.
ADJACENT = {
    ("chest", "head"): "neck",
    ("waist", "chest"): "chest",
    ("chest", "upper_arm_l"): "shoulder_l",
    ("chest", "upper_arm_r"): "shoulder_r",
    ("upper_arm_l", "forearm_l"): "elbow_l",
    ("upper_arm_r", "forearm_r"): "elbow_r",
    ("waist", "thigh_l"): "hip_l",
    ("waist", "thigh_r"): "hip_r",
    ("thigh_l", "lower_leg_l"): "knee_l",
    ("thigh_r", "lower_leg_r"): "knee_r",
}


#: Hands and feet (beyond the paper's model, `recon.posture.extremities`): name -> (the section they
#: continue and are scored as, the joint between them).
EXTREMITIES = {
    "hand_l": ("forearm_l", "wrist_l"), "hand_r": ("forearm_r", "wrist_r"),
    "foot_l": ("lower_leg_l", "ankle_l"), "foot_r": ("lower_leg_r", "ankle_r"),
}


def adjacency_matrix() -> np.ndarray:
    """(11, 11) bool: True where two sections meet at a joint (symmetric, False on the diagonal)."""
    m = np.zeros((len(SECTIONS), len(SECTIONS)), dtype=bool)
    for a, b in ADJACENT:
        i, j = SECTIONS.index(a), SECTIONS.index(b)
        m[i, j] = m[j, i] = True
    return m


@dataclass(frozen=True, eq=False)
class BodyFit:
    """The body model fitted to a cloud: the result of posture estimation (paper section 2).

    Attributes
    ----------
    sections : dict of str to SectionShape
        Fitted sections, by name; a section that could not be fitted is absent.
    joints : dict of str to (3,) float
        Joint positions by canonical name (pelvis, chest, neck, head, shoulder_l, ...), metres: the
        fit's estimate of the body's joints (reported, and scored against the truth). Those of
        unfitted sections are absent, and so is an elbow or knee whose distal section is unfitted
        (`recon.posture.fit._reported_joints`).
    residuals : dict of str to float
        Per fitted section, RMS distance (metres) of its points to its model surface.
    unfitted : tuple of str
        Sections missing from the scan (or too poorly covered to fit).
    coarse : BodyFit or None
        The fit before the fine adjustment on the points (for previews), if kept.
    times : dict of str to float
        Seconds spent in each stage of the fit (e.g. ``voxelize``, ``match``, ``fine``).
    extremities : dict of str to SectionShape
        Hands and feet placed past the wrists and ankles (`EXTREMITIES`,
        `recon.posture.extremities.place_extremities`); empty in the paper's model.
    seams : dict of str to (3,) float
        Where the sections meet, by joint name, metres (`recon.posture.joints.place_seams`): the
        clustering's joint planes and bones, and the cuts of the hands and feet, are taken from
        these, not from ``joints``. None (the default) takes ``joints``; so does a fit file without
        them (`from_dict`). ``dataclasses.replace(fit, joints=...)`` keeps the seams.
    """

    sections: dict
    joints: dict
    residuals: dict = field(default_factory=dict)
    unfitted: tuple = ()
    coarse: "BodyFit | None" = None
    times: dict = field(default_factory=dict)
    extremities: dict = field(default_factory=dict)
    seams: "dict | None" = None

    def __post_init__(self):
        if self.seams is None:
            object.__setattr__(self, "seams", self.joints)

    def to_dict(self) -> dict:
        """JSON-ready: ``{"joints": {name: [x, y, z]}, "seams": {...}, "sections": {name: {...}}, ...}``."""
        d = {
            "joints": {k: np.asarray(v, dtype=float).tolist() for k, v in self.joints.items()},
            "seams": {k: np.asarray(v, dtype=float).tolist() for k, v in self.seams.items()},
            "sections": {k: {**s.to_dict(), "residual_m": self.residuals.get(k)}
                         for k, s in self.sections.items()},
            "unfitted": list(self.unfitted),
            "times_s": dict(self.times),
        }
        if self.extremities:
            d["extremities"] = {k: s.to_dict() for k, s in self.extremities.items()}
        if self.coarse is not None:
            d["coarse"] = self.coarse.to_dict()
        return d

    def moved(self, R: np.ndarray, t: np.ndarray) -> "BodyFit":
        """The fit carried by the rigid motion ``p -> R @ p + t`` (R (3, 3) a rotation, t (3,))."""
        R = np.asarray(R, dtype=np.float64)
        return replace(self, sections={k: s.moved(R, t) for k, s in self.sections.items()},
                       joints={k: R @ np.asarray(v, dtype=float) + t for k, v in self.joints.items()},
                       seams={k: R @ np.asarray(v, dtype=float) + t for k, v in self.seams.items()},
                       coarse=self.coarse.moved(R, t) if self.coarse is not None else None,
                       extremities={k: s.moved(R, t) for k, s in self.extremities.items()})

    @classmethod
    def from_dict(cls, d: dict) -> "BodyFit":
        return cls(
            sections={k: SectionShape.from_dict(k, v) for k, v in d["sections"].items()},
            joints={k: np.asarray(v, dtype=float) for k, v in d["joints"].items()},
            seams={k: np.asarray(v, dtype=float) for k, v in d["seams"].items()} if "seams" in d else None,
            residuals={k: v["residual_m"] for k, v in d["sections"].items() if v.get("residual_m") is not None},
            unfitted=tuple(d.get("unfitted", ())),
            coarse=cls.from_dict(d["coarse"]) if d.get("coarse") else None,
            times=dict(d.get("times_s", {})),
            extremities={k: SectionShape.from_dict(k, v) for k, v in d.get("extremities", {}).items()},
        )
