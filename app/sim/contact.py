"""Box–box contact between mockups: coal geometry + a compliant, no-pull contact law.

Implements DESIGN.md, "Contact between mockups": penetration depth, normal and point from
coal (boxes of each satellite's size_m at their COM poses T_W_C), a Hunt–Crossley law
F_n = max(0, k d (1 + c ḋ)) with per-mockup materials, Coulomb friction in the tangent
plane, and equal and opposite forces at the contact point. Works for any number of bodies
(all pairs, or a chosen list).

Friction: a regularised Coulomb law (the smooth approximation of the sign function used
for stiff contact integration, e.g. in MuJoCo's and Drake's compliant friction models),

    F_t = μ F_n v_t / sqrt(|v_t|² + v_ε²),                                    (Coulomb)

v_t the tangential sliding velocity at the contact point, v_ε = FRICTION_SLIP_MPS: while
the surfaces slide faster than a few v_ε the tangential force is μ F_n against the slip
(Coulomb's law); at v_t = 0 it is zero and it grows continuously, so the ideal run's
sub-stepped integration stays smooth. μ of two surfaces: √(μ_a μ_b).

Material combination for two surfaces pressed against each other:

* stiffness: springs in series, k = k_a k_b / (k_a + k_b);
* damping: the two surfaces deflect in proportion to their compliance (d_i = d k / k_i),
  and the combined c is chosen so that the damping power equals the sum of both surfaces'
  (first order in c): c = (c_a / k_a + c_b / k_b) / (1 / k_a + 1 / k_b), the
  compliance-weighted mean; the softer surface dominates, a material with itself keeps c.

Frames: everything in the lab frame W. The normal points from body a towards body b of a
pair (a < b); body b is pushed along +normal, body a along −normal.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import combinations

import coal
import numpy as np
from numba import njit

from app.config import DEFAULT_MATERIALS, ContactMaterial, SatelliteConfig
from app.sim.rotations import cross3_floats, minus3_floats, point_velocity_floats

__all__ = [
    "APART_GAP_M",
    "APART_SLACK",
    "BoxContactModel",
    "ContactGeometry",
    "ContactResult",
    "PairContact",
    "combine_friction",
    "combine_materials",
    "coulomb_friction",
    "hunt_crossley_force",
]


def combine_materials(a: ContactMaterial, b: ContactMaterial) -> tuple[float, float]:
    """(k_eff N/m, c_eff s/m) of two surfaces in contact (series springs, see module doc)."""
    ca, cb = 1.0 / a.stiffness_Npm, 1.0 / b.stiffness_Npm  # compliances
    k = 1.0 / (ca + cb)
    c = (a.damping_spm * ca + b.damping_spm * cb) / (ca + cb)
    return k, c


FRICTION_SLIP_MPS = 1e-3
"""v_ε of the regularised Coulomb law: below about this sliding speed friction fades to 0."""


def combine_friction(a: ContactMaterial, b: ContactMaterial) -> float:
    """μ of two surfaces in contact: the geometric mean √(μ_a μ_b) (a frictionless surface
    slides on anything)."""
    return math.sqrt(a.friction * b.friction)


def coulomb_friction(normal_force_N: float, slip_W_mps: np.ndarray, mu: float) -> np.ndarray:
    """(3,) regularised Coulomb friction (module doc, Coulomb) on the body that the other
    slides past at ``slip_W_mps`` (the other body's tangential velocity relative to it at
    the contact point): μ F_n along the slip, faded out below FRICTION_SLIP_MPS."""
    if mu == 0.0 or normal_force_N == 0.0:
        return np.zeros(3)
    speed_sq = float(slip_W_mps.dot(slip_W_mps))
    return (mu * normal_force_N / math.sqrt(speed_sq + FRICTION_SLIP_MPS**2)) * slip_W_mps


def hunt_crossley_force(
    depth_m: float, depth_rate_mps: float, stiffness_Npm: float, damping_spm: float,
    exponent: float = 1.0,
) -> float:
    """Normal force (N, ≥ 0) of the law F = k dⁿ (1 + c ḋ), n = ``exponent`` (1: linear);
    zero when not overlapping.

    The clamp at zero is the no-pull condition: a fast-separating contact (ḋ < −1/c)
    exerts no adhesive force.
    """
    if depth_m <= 0.0:
        return 0.0
    spring = depth_m if exponent == 1.0 else depth_m**exponent
    return max(0.0, stiffness_Npm * spring * (1.0 + damping_spm * depth_rate_mps))


@dataclass(frozen=True)
class ContactGeometry:
    """Overlap of two boxes as coal reports it."""

    depth_m: float
    """Penetration depth, > 0 when overlapping."""
    normal_W: np.ndarray
    """(3,) unit normal from body a towards body b."""
    point_W_m: np.ndarray
    """(3,) contact point (midway between the two surfaces' deepest points)."""


@dataclass(frozen=True)
class PairContact:
    """One active contact between bodies a and b."""

    a: int
    b: int
    geometry: ContactGeometry
    depth_rate_mps: float
    """ḋ: rate of approach of the two bodies at the contact point along the normal."""
    normal_force_N: float
    """F_n ≥ 0; force on b is +F_n·normal + friction_W, on a the opposite."""
    friction_W: np.ndarray | None = None
    """(3,) the tangential (friction) force on b, W axes; None: frictionless pair."""


@dataclass(frozen=True)
class ContactResult:
    """Contact wrenches on every body for one instant."""

    wrench_W: np.ndarray
    """(N, 6): per body, force in W (N) and its moment about that body's COM (N·m, W)."""
    contacts: tuple[PairContact, ...]


def _add(acc: list[float], x: list[float], sign: float) -> None:
    """acc += x (sign 1) or acc -= x (sign -1), in place, element by element."""
    if sign > 0.0:
        for k, value in enumerate(x):
            acc[k] += value
    else:
        for k, value in enumerate(x):
            acc[k] -= value


APART_SLACK = 1e-9
"""Relative slack of :meth:`BoxContactModel.apart`'s plain-float test: far more than the
last bits by which its sum of three squares can differ from the arrays' dot product (a
few ulps, ~1e-16 relative: the terms are all ≥ 0, nothing cancels)."""

APART_GAP_M = 1e-4
"""How much further apart than asked two boxes must be for :meth:`BoxContactModel.apart`
to vouch for them where their bounding spheres overlap (m): over a hundred times the
error of coal's box–box distance (up to 6e-7 m measured here: its GJK stops at a
tolerance), so that a pair it calls apart is one that coal's queries find apart too
(tests/test_contact.py)."""


@njit(cache=True, fastmath=False)
def _faces_separate(T_a, T_b, half_a, half_b, dx, dy, dz, gap_m):
    """Whether a face axis of box a or of box b (poses T_a, T_b (4, 4), half edge lengths
    half_a, half_b, centre offset (dx, dy, dz) from a to b) separates them by more than
    gap_m: the separating-axis theorem's face axes, whose gaps are lower bounds of the
    boxes' distance. NaN separates nothing."""
    for box in range(2):
        T = T_a if box == 0 else T_b
        for k in range(3):
            ux, uy, uz = T[0, k], T[1, k], T[2, k]
            gap = abs(dx * ux + dy * uy + dz * uz)
            for j in range(3):
                gap -= half_a[j] * abs(ux * T_a[0, j] + uy * T_a[1, j] + uz * T_a[2, j])
                gap -= half_b[j] * abs(ux * T_b[0, j] + uy * T_b[1, j] + uz * T_b[2, j])
            if gap > gap_m:
                return True
    return False


@njit(cache=True, fastmath=False)
def boxes_apart(T_W_C, pairs, half_m, radii_m, within_m, slack, gap_m):
    """Whether each pair (a, b) of pairs (P, 2) is clearly out of reach at the COM poses
    T_W_C (N, 4, 4): its bounding spheres (radii_m) more than within_m apart by a relative
    ``slack`` in the squared distance, or a face axis of one box separating the boxes
    (half edge lengths half_m (N, 3)) by more than ``within_m + gap_m``
    (:func:`_faces_separate`). A NaN pose is never apart. ValueError: poses of another
    shape than (N, 4, 4) (or (N, 3, 4)) for the model's N bodies."""
    if (T_W_C.shape[0] < half_m.shape[0] or T_W_C.shape[1] < 3 or T_W_C.shape[1] > 4
            or T_W_C.shape[2] != 4):
        raise ValueError("apart: the poses must be one (4, 4) per body of the model")
    for k in range(pairs.shape[0]):
        a, b = pairs[k, 0], pairs[k, 1]
        dx = T_W_C[b, 0, 3] - T_W_C[a, 0, 3]
        dy = T_W_C[b, 1, 3] - T_W_C[a, 1, 3]
        dz = T_W_C[b, 2, 3] - T_W_C[a, 2, 3]
        reach = radii_m[a] + radii_m[b] + within_m
        if dx * dx + dy * dy + dz * dz > reach * reach * slack:
            continue
        if not _faces_separate(T_W_C[a], T_W_C[b], half_m[a], half_m[b], dx, dy, dz,
                               within_m + gap_m):
            return False
    return True


def _holds_coal(value) -> bool:
    """Whether a value is a coal object or a list/dict of them."""
    if isinstance(value, dict):
        value = list(value.values())
    if isinstance(value, (list, tuple)):
        return any(_holds_coal(v) for v in value)
    return type(value).__module__.split(".")[0] in ("coal", "hppfcl")


class BoxContactModel:
    """Contacts among N box-shaped mockups, reusing coal objects between calls.

    sizes_m: full edge lengths (3,) per body (box centred on the COM, edges along the body
    axes); materials: per body; pairs: which (a, b) pairs may touch (default: all).
    """

    def __init__(
        self,
        sizes_m: Sequence[Sequence[float]],
        materials: Sequence[ContactMaterial],
        pairs: Sequence[tuple[int, int]] | None = None,
    ) -> None:
        if len(sizes_m) != len(materials):
            raise ValueError("one material per box is needed")
        self.n = len(sizes_m)
        self._sizes_m = [tuple(map(float, s)) for s in sizes_m]
        self._radii = [0.5 * math.sqrt(sum(x * x for x in s)) for s in sizes_m]
        if pairs is None:
            pairs = list(combinations(range(self.n), 2))
        self.pairs = [(min(a, b), max(a, b)) for a, b in pairs]
        self._half_m = 0.5 * np.array(self._sizes_m)
        self._radii_m = np.array(self._radii)
        self._law = {(a, b): combine_materials(materials[a], materials[b]) for a, b in self.pairs}
        self._mu = {(a, b): combine_friction(materials[a], materials[b]) for a, b in self.pairs}
        self._exponent = {(a, b): max(materials[a].exponent, materials[b].exponent)
                          for a, b in self.pairs}
        self.frames: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        """Per pair (a < b), the last contact frame :meth:`clearances` measured within its
        margin: (unit normal from a towards b, contact point), W; kept once they part."""
        self._build_coal()

    @property
    def pairs(self) -> list[tuple[int, int]]:
        """The pairs (a < b) that may touch; :meth:`apart` reads them as an array, made
        anew whenever they are set."""
        return self._pairs

    @pairs.setter
    def pairs(self, pairs: Sequence[tuple[int, int]]) -> None:
        self._pairs = list(pairs)
        self._pair_index = np.array(self._pairs, dtype=np.int64).reshape(-1, 2)

    def _build_coal(self) -> None:
        """The coal objects (shapes, poses, solvers, requests, results): scratch state,
        rebuilt from the sizes whenever the model is copied."""
        self._shapes = [coal.Box(*s) for s in self._sizes_m]
        self._tf = [coal.Transform3s() for _ in self._sizes_m]
        every = list(combinations(range(self.n), 2))  # a copy may still be asked any pair
        self._solvers = {
            (a, b): coal.ComputeCollision(self._shapes[a], self._shapes[b]) for a, b in every
        }
        self._request = coal.CollisionRequest()
        self._request.enable_contact = True
        self._request.num_max_contacts = 1
        self._result = coal.CollisionResult()
        self._distance = {
            (a, b): coal.ComputeDistance(self._shapes[a], self._shapes[b]) for a, b in every
        }
        self._distance_request = coal.DistanceRequest()
        self._distance_result = coal.DistanceResult()

    def __deepcopy__(self, memo: dict) -> BoxContactModel:
        """A copy with its own coal objects (coal's solvers cannot be copied; they hold no
        state between calls): what an Emulator snapshot needs (app/runs/uncertainty.py)."""
        new = BoxContactModel.__new__(BoxContactModel)
        memo[id(self)] = new
        for key, value in self.__dict__.items():
            if not _holds_coal(value):
                new.__dict__[key] = copy.deepcopy(value, memo)
        new._build_coal()
        return new

    @classmethod
    def from_satellites(
        cls,
        satellites: Sequence[SatelliteConfig],
        materials: Mapping[str, ContactMaterial] = DEFAULT_MATERIALS,
        built: bool = False,
    ) -> BoxContactModel:
        """Boxes of each satellite's size_m with its named material; ``built``: as the
        mockups were built, size_m + size_error_m along each axis (the physics' boxes)."""
        sizes = [tuple(x + (s.size_error_m if built else 0.0) for x in s.size_m)
                 for s in satellites]
        return cls(sizes, [materials[s.material] for s in satellites])

    def exclude(self, a: int, b: int) -> None:
        """Bodies a and b no longer touch (they were latched together: their contact is
        internal to one body)."""
        self.pairs = [p for p in self.pairs if p != (min(a, b), max(a, b))]

    def law(self, a: int, b: int) -> tuple[float, float]:
        """(k_eff, c_eff) used for the pair (a, b)."""
        return self._law[(min(a, b), max(a, b))]

    def friction(self, a: int, b: int) -> float:
        """μ of the pair (a, b) (its materials' setting: configuration, not measurement)."""
        return self._mu[(min(a, b), max(a, b))]

    def _set_pose(self, i: int, T_W_C: np.ndarray) -> None:
        self._tf[i].setRotation(T_W_C[:3, :3])
        self._tf[i].setTranslation(T_W_C[:3, 3])

    def geometry(
        self, a: int, b: int, T_W_Ca: np.ndarray, T_W_Cb: np.ndarray
    ) -> ContactGeometry | None:
        """Penetration of boxes a < b at the given COM poses; None when apart."""
        d_ab = T_W_Cb[:3, 3] - T_W_Ca[:3, 3]
        reach = self._radii[a] + self._radii[b]
        if float(d_ab.dot(d_ab)) > reach * reach:  # bounding spheres apart: cheap early-out
            return None
        self._set_pose(a, T_W_Ca)
        self._set_pose(b, T_W_Cb)
        res = self._result
        res.clear()
        if not self._solvers[(a, b)](self._tf[a], self._tf[b], self._request, res):
            return None
        c = res.getContact(0)
        depth = -float(c.penetration_depth)  # coal: signed distance, < 0 when overlapping
        if depth <= 0.0:
            return None
        return ContactGeometry(depth, np.array(c.normal, dtype=float), np.array(c.pos))

    def apart(self, T_W_C: Sequence[np.ndarray], within_m: float = 0.0) -> bool:
        """Whether every pair that may touch is clearly out of reach at the COM poses
        T_W_C (:func:`boxes_apart`): its bounding spheres more than ``within_m`` apart,
        beyond APART_SLACK, or a face of one box turned to the other with more than
        ``within_m`` + APART_GAP_M between them. Where it holds, :meth:`geometry` (within_m
        0) and :meth:`clearances` (their within_m) find nothing: the arrays' bounding-sphere
        test skips the pair (the same differences, exact IEEE subtractions; a sum of squares
        within a few ulps of the arrays' dot product), or coal measures the boxes further
        apart than within_m. It saves their calls in free flight and on the approach (the
        loop's contact gate, :class:`app.sim.interaction.PhysicalInteraction`)."""
        if not self._pairs:  # (the property's list, without its call: every cycle)
            return True
        if type(T_W_C) is not np.ndarray:  # (the kernel's one layout: (N, 4, 4) C-ordered)
            T_W_C = np.array(T_W_C, dtype=float)
        return boxes_apart(T_W_C, self._pair_index, self._half_m, self._radii_m, within_m,
                           1.0 + APART_SLACK, APART_GAP_M)

    def overlapping(self, T_W_C: Sequence[np.ndarray]) -> bool:
        """Whether any pair that may touch overlaps at the COM poses T_W_C: whether
        :meth:`compute` there would report a contact (the same geometry, no velocities)."""
        return any(self.geometry(a, b, T_W_C[a], T_W_C[b]) is not None for a, b in self._pairs)

    def clearances(self, T_W_C: Sequence[np.ndarray],
                   within_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """((N,) clearance, (N,) nearest, (N,) crowd): per body, the signed distance (m,
        < 0 when overlapping) to the nearest body it may touch and that body's index, if
        nearer than ``within_m`` (inf and -1 otherwise), and how many bodies are nearer
        than ``within_m`` (bounding spheres further apart than that are not measured).
        Each pair within ``within_m`` also has its contact frame in :attr:`frames`
        (:meth:`_frame`)."""
        n = self.n
        out, nearest, crowd = [math.inf] * n, [-1] * n, [0] * n  # lists: a few bodies
        radii = self._radii
        for a, b in self._pairs:
            d_ab = T_W_C[b][:3, 3] - T_W_C[a][:3, 3]
            reach = radii[a] + radii[b] + within_m
            if float(d_ab.dot(d_ab)) > reach * reach:
                continue
            self._set_pose(a, T_W_C[a])
            self._set_pose(b, T_W_C[b])
            res = self._distance_result
            res.clear()
            d = float(self._distance[(a, b)](self._tf[a], self._tf[b],
                                              self._distance_request, res))
            if d < within_m:
                self.frames[(a, b)] = self._frame(a, b, T_W_C, res)
                crowd[a] += 1
                crowd[b] += 1
                if d < out[a]:
                    out[a], nearest[a] = d, b
                if d < out[b]:
                    out[b], nearest[b] = d, a
        return (np.array(out), np.array(nearest, dtype=np.int64),
                np.array(crowd, dtype=np.int64))

    def _frame(self, a: int, b: int, T_W_C: Sequence[np.ndarray],
               res) -> tuple[np.ndarray, np.ndarray]:
        """(normal a → b, contact point) of a pair within the margin. The normal is the
        signed-distance query's; the point lies on the contact plane (through the
        midpoint of the query's two nearest points) under the midpoint of the two COMs:
        the centre of the overlap of two equal faces, however they are offset. (The
        query's own points are any of the face's: for two parallel faces GJK and EPA
        return a corner, a lever arm of half the face the contact does not have.) The
        sums and products on plain floats (the same operations as on arrays); the
        projection's dot product is the arrays'."""
        normal = np.array(res.normal, dtype=float)
        n = normal.tolist()
        p1, p2 = res.getNearestPoint1().tolist(), res.getNearestPoint2().tolist()
        c_a, c_b = T_W_C[a][:3, 3].tolist(), T_W_C[b][:3, 3].tolist()
        mid = [0.5 * (c_a[k] + c_b[k]) for k in range(3)]
        off = np.array([0.5 * (p1[k] + p2[k]) - mid[k] for k in range(3)])
        along = float(off.dot(normal))
        return normal, np.array([mid[k] + along * n[k] for k in range(3)])

    def compute(
        self,
        T_W_C: Sequence[np.ndarray],
        v_W_mps: np.ndarray | None = None,
        omega_W_radps: np.ndarray | None = None,
    ) -> ContactResult:
        """Contact wrenches on all bodies.

        T_W_C: (N,) COM poses (4x4); v_W_mps: (N, 3) COM velocities in W; omega_W_radps:
        (N, 3) angular velocities in W axes (None: zero). Returns per-body force in W and its
        moment about the body's COM; forces within a pair are exactly equal and opposite.
        """
        v = (np.zeros((self.n, 3)) if v_W_mps is None
             else np.asarray(v_W_mps, dtype=float))
        w = (np.zeros((self.n, 3)) if omega_W_radps is None
             else np.asarray(omega_W_radps, dtype=float))
        wrench = None  # per body [f, τ] as plain floats (a few of them: list arithmetic,
        contacts = []  # the same IEEE operations as the arrays' in the same order)
        v_l = w_l = None  # the velocities as floats, once a pair overlaps
        for a, b in self._pairs:
            geo = self.geometry(a, b, T_W_C[a], T_W_C[b])
            if geo is None:
                continue
            if v_l is None:
                v_l, w_l = v.tolist(), w.tolist()
            p, n = geo.point_W_m.tolist(), geo.normal_W
            r_a = minus3_floats(p, T_W_C[a][:3, 3].tolist())
            r_b = minus3_floats(p, T_W_C[b][:3, 3].tolist())
            v_a = point_velocity_floats(v_l[a], w_l[a], r_a)
            v_b = point_velocity_floats(v_l[b], w_l[b], r_b)
            v_rel = np.array(minus3_floats(v_a, v_b))
            depth_rate = float(v_rel.dot(n))  # > 0 while approaching
            f_n = hunt_crossley_force(geo.depth_m, depth_rate, *self._law[(a, b)],
                                      self._exponent[(a, b)])
            mu = self._mu[(a, b)]
            friction = (None if mu == 0.0
                        else coulomb_friction(f_n, v_rel - depth_rate * n, mu))
            contacts.append(PairContact(a, b, geo, depth_rate, f_n, friction))
            if f_n == 0.0:
                continue
            f_b = (f_n * n if friction is None else f_n * n + friction).tolist()
            if wrench is None:
                wrench = [[0.0] * 6 for _ in range(self.n)]
            _add(wrench[b], f_b + cross3_floats(r_b, f_b), 1.0)
            _add(wrench[a], f_b + cross3_floats(r_a, f_b), -1.0)
        return ContactResult(np.zeros((self.n, 6)) if wrench is None else np.array(wrench),
                             tuple(contacts))
