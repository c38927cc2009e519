"""One TPU leg as a planar, geometrically exact Cosserat rod (staggered discretisation).

Positions r_i = (s_i, z_i) live on the N nodes, in the leg's vertical plane (s along
the leg's horizontal direction from the root, z world height); cross-section angles
theta_e live on the N-1 elements, with tangent director d3 = (cos, sin) and normal
d1 = (-sin, cos). For element e with Delta = r_{e+1} - r_e and rest length l0:

    a = Delta . d3,  b = Delta . d1,   axial strain eps = a/l0 - 1,  shear gamma = b/l0
    U_e = 1/2 EA/l0 (a - l0)^2 + 1/2 kGA/l0 b^2

and at each interior vertex v (between elements v-1 and v, Voronoi length D_v):

    U_v = 1/2 EI_v / D_v (theta_v - theta_{v-1} - dtheta0_v)^2

Forces and moments are -grad U, so stretch, shear and bending all act on positions
and angles together: the leg holds its shape by its own elasticity. (The paper's
eqs. 2-4 omit the shear coupling between angles and positions and need a
"restoring spring"; :func:`paper_elastic_forces` reproduces that model for comparison.)
The Hessian is analytic and banded (half-bandwidth 4 in the interleaved ordering
x0 z0 th0 x1 z1 th1 ...), which the linearly implicit integrator uses; it factors
its matrix with :func:`banded_factor` (LU without pivoting: the lumped mass
diagonal dominates) and solves with :func:`banded_substitute`.

Every kernel reads an element's Delta and its components a, b through
:func:`element_kinematics`, and the vertex bending through :func:`bending_moments`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..config import LegConfig
from ..jit import njit
from ..robot import rest_shape_points

POISSON = 0.45  # TPU is nearly incompressible
SHEAR_COEFF = 5.0 / 6.0  # rectangular section


class LegModel(NamedTuple):
    """Discretised leg: rest geometry, stiffness, lumped inertia (all SI).

    A named tuple of arrays, so the numba kernels take it whole (its properties are Python's only).
    """

    rest_pos: np.ndarray  # (N, 2)
    rest_theta: np.ndarray  # (E,)
    l0: np.ndarray  # (E,) rest element lengths
    voronoi: np.ndarray  # (N,) D_v (0 at the two end nodes)
    dtheta0: np.ndarray  # (N,) rest angle jump at each interior vertex
    ea: np.ndarray  # (E,) axial stiffness E A
    ga: np.ndarray  # (E,) shear stiffness k G A
    ei: np.ndarray  # (N,) bending stiffness E I at vertices
    mass: np.ndarray  # (N,) lumped node masses
    inertia: np.ndarray  # (E,) element rotational inertia rho I l0

    @property
    def n_nodes(self) -> int:
        return self.rest_pos.shape[0]

    @property
    def length(self) -> float:
        return float(self.l0.sum())


def node_arclengths(cfg: LegConfig, anchor_fraction: float, n_nodes: int | None = None) -> tuple[np.ndarray, int]:
    """The nodes' arc lengths from the root (m) and the tendon's anchor node: ``n_nodes`` (``cfg.n_nodes``) evenly
    spaced, the anchor the one nearest ``anchor_fraction`` of the way down, and the element before it split into
    ``cfg.anchor_refinement``.

    Why there: the cable bends the leg with the moment T d up to its anchor and not beyond, and the staggered rod
    takes the turn it is pulled through to the last routed element's angle, at that element's middle. So its moment
    bends a span half an element short of the anchor: an error first order in that element's length (measured on the
    free leg at 80 deg of tendon, 31 nodes: the tension 6 % and the tip's travel 2 % off the converged rod, halving
    with the element). Splitting that one element shrinks it where it arises; the rest of the leg converges faster
    (a tip load's deflection at 31 nodes is within 0.01 mm of 241 nodes')."""
    n = int(n_nodes or cfg.n_nodes)
    s = np.linspace(0.0, cfg.length, n)
    anchor = max(1, int(round(anchor_fraction * (n - 1))))
    r = int(cfg.anchor_refinement)
    if r > 1:
        inner = s[anchor - 1] + (s[anchor] - s[anchor - 1]) * np.arange(1, r) / r
        s = np.concatenate([s[:anchor], inner, s[anchor:]])
        anchor += r - 1
    return s, anchor


def build_leg(cfg: LegConfig, n_nodes: int | None = None, anchor_fraction: float | None = None) -> LegModel:
    """The leg of ``cfg``: rest shape, linear thickness taper, lumped masses; with ``anchor_fraction`` (the
    tendon's ``routed_fraction``) its mesh refined before the tendon's anchor (:func:`node_arclengths`)."""
    n = int(n_nodes or cfg.n_nodes)
    s_nodes = None
    if anchor_fraction is not None and cfg.anchor_refinement > 1:
        s_nodes = node_arclengths(cfg, anchor_fraction, n)[0]
    if cfg.rest_shape == "cubic":
        shape = rest_shape_points(cfg.rest_shape_coeffs, cfg.length, n, s_nodes)
    else:  # straight and horizontal, at the root height of the cubic
        x = np.linspace(0.0, cfg.length, n) if s_nodes is None else s_nodes
        shape = np.column_stack([x, np.full(x.shape[0], cfg.rest_shape_coeffs[-1])])
    return model_from_shape(shape, cfg.width, cfg.thickness_root, cfg.thickness_tip, cfg.youngs_modulus, cfg.density)


def lateral_stiffness(cfg: LegConfig) -> float:
    """The leg's stiffness across its plane at the tip, N/m: 0 where ``cfg.out_of_plane`` is rigid.

    A sideways force F at the tip of the tapered strip (width w across the plane, thickness t(s)
    in it) bends it about its stiff axis, I = t w^3 / 12, so the tip moves F / k with
    1/k = int_0^L (L - s)^2 / (E I(s)) ds along the rod's arc length L (Euler-Bernoulli, straight).
    That is about 4x the in-plane tip stiffness (w/t is 1.5-6), but still only tens of N/m: a
    foot holding mu N = 2 N sideways sits 70 mm off its rigid place. The leg's twist and its
    curl make it softer still, so this is an upper bound on the stiffness.
    """
    if cfg.out_of_plane == "rigid":
        return 0.0
    length = build_leg(cfg).length
    ds = length / 4000
    s = (np.arange(4000) + 0.5) * ds  # midpoint rule
    t = cfg.thickness_root + (cfg.thickness_tip - cfg.thickness_root) * s / length
    second_moment = t * cfg.width**3 / 12.0
    return float(1.0 / np.sum((length - s) ** 2 / (cfg.youngs_modulus * second_moment) * ds))


def model_from_shape(
    shape: np.ndarray, width: float, h_root: float, h_tip: float, youngs: float, density: float
) -> LegModel:
    shape = np.asarray(shape, dtype=float)
    delta = np.diff(shape, axis=0)
    l0 = np.hypot(delta[:, 0], delta[:, 1])
    theta = np.unwrap(np.arctan2(delta[:, 1], delta[:, 0]))
    s_nodes = np.concatenate([[0.0], np.cumsum(l0)])
    length = s_nodes[-1]
    s_mid = 0.5 * (s_nodes[1:] + s_nodes[:-1])
    h_elem = h_root + (h_tip - h_root) * s_mid / length
    h_node = h_root + (h_tip - h_root) * s_nodes / length
    shear_modulus = youngs / (2.0 * (1.0 + POISSON))
    area = width * h_elem
    n = shape.shape[0]
    voronoi = np.zeros(n)
    voronoi[1:-1] = 0.5 * (l0[1:] + l0[:-1])
    voronoi[0] = 0.5 * l0[0]  # the clamp: element 0 bends against the root's angle over half an element
    dtheta0 = np.zeros(n)
    dtheta0[1:-1] = np.diff(theta)
    mass = np.zeros(n)
    m_elem = density * area * l0
    mass[:-1] += 0.5 * m_elem
    mass[1:] += 0.5 * m_elem
    return LegModel(
        rest_pos=shape.copy(),
        rest_theta=theta,
        l0=l0,
        voronoi=voronoi,
        dtheta0=dtheta0,
        ea=youngs * area,
        ga=SHEAR_COEFF * shear_modulus * area,
        ei=youngs * width * h_node**3 / 12.0,
        mass=mass,
        inertia=density * width * h_elem**3 / 12.0 * l0,
    )


@njit(cache=True, allocates=False)
def directors(theta, cth, sth):
    """cos and sin of every element angle, computed once per step and shared."""
    for e in range(theta.shape[0]):
        cth[e] = np.cos(theta[e])
        sth[e] = np.sin(theta[e])


@njit(cache=True, allocates=False)
def element_kinematics(pos, e, c, s):
    """Element ``e``'s Delta = r_{e+1} - r_e and its components along the directors.

    ``c``, ``s`` are cos and sin of the element's angle; returns (dx, dz, a, b) with
    a = Delta . d3 (axial) and b = Delta . d1 (shear).
    """
    dx = pos[e + 1, 0] - pos[e, 0]
    dz = pos[e + 1, 1] - pos[e, 1]
    return dx, dz, dx * c + dz * s, -dx * s + dz * c


@njit(cache=True, allocates=False)
def bending_moments(theta, theta_root, voronoi, dtheta0, ei, moment) -> float:
    """Add -dU_v/dtheta of every vertex, the clamp at the root included, into ``moment``.

    Returns the clamp's moment, the bending moment the leg exerts on its root.
    """
    n_el = theta.shape[0]
    for v in range(1, n_el):
        m = ei[v] / voronoi[v] * (theta[v] - theta[v - 1] - dtheta0[v])
        moment[v] -= m
        moment[v - 1] += m
    m_root = ei[0] / voronoi[0] * (theta[0] - theta_root)
    moment[0] -= m_root
    return m_root


@njit(cache=True)
def elastic_forces(pos, theta, theta_root, l0, voronoi, dtheta0, ea, ga, ei, force, moment) -> float:
    """Add -grad U (stretch, shear, bending) into ``force`` (N, 2) and ``moment`` (E,).

    ``theta_root`` is the clamp angle at node 0 (rest: theta[0]); returns the bending
    moment the leg exerts on its root.
    """
    cth = np.empty(theta.shape[0])
    sth = np.empty(theta.shape[0])
    directors(theta, cth, sth)
    return elastic_forces_cs(pos, theta, cth, sth, theta_root, l0, voronoi, dtheta0, ea, ga, ei, force, moment)


@njit(cache=True, allocates=False)
def elastic_forces_cs(pos, theta, cth, sth, theta_root, l0, voronoi, dtheta0, ea, ga, ei, force, moment) -> float:
    """:func:`elastic_forces` with the directors given."""
    n_el = theta.shape[0]
    for e in range(n_el):
        c = cth[e]
        s = sth[e]
        _, _, a, b = element_kinematics(pos, e, c, s)
        ka = ea[e] / l0[e]
        ks = ga[e] / l0[e]
        na = ka * (a - l0[e])
        ns = ks * b
        gx = na * c - ns * s
        gz = na * s + ns * c
        force[e, 0] += gx
        force[e, 1] += gz
        force[e + 1, 0] -= gx
        force[e + 1, 1] -= gz
        moment[e] += b * (ks * a - na)
    return bending_moments(theta, theta_root, voronoi, dtheta0, ei, moment)


@njit(cache=True, allocates=False)
def elastic_energy(pos, theta, theta_root, l0, voronoi, dtheta0, ea, ga, ei) -> float:
    n_el = theta.shape[0]
    u = 0.0
    for e in range(n_el):
        c = np.cos(theta[e])
        s = np.sin(theta[e])
        _, _, a, b = element_kinematics(pos, e, c, s)
        u += 0.5 * ea[e] / l0[e] * (a - l0[e]) ** 2 + 0.5 * ga[e] / l0[e] * b * b
    for v in range(1, n_el):
        d = theta[v] - theta[v - 1] - dtheta0[v]
        u += 0.5 * ei[v] / voronoi[v] * d * d
    u += 0.5 * ei[0] / voronoi[0] * (theta[0] - theta_root) ** 2
    return u


@njit(cache=True)
def elastic_hessian_band(pos, theta, theta_root, l0, voronoi, dtheta0, ea, ga, ei, band, scale):
    """Add ``scale`` * Hessian of U into ``band`` (n, 9): band[i, 4 + j - i] = H[i, j].

    (U is quadratic in theta_root, so the Hessian does not depend on it.)
    DOF order: node i -> 3i, 3i+1; element e -> 3e+2 (so n = 3N - 1).
    """
    cth = np.empty(theta.shape[0])
    sth = np.empty(theta.shape[0])
    directors(theta, cth, sth)
    elastic_hessian_cs(pos, theta, cth, sth, l0, voronoi, ea, ga, ei, band, scale)


@njit(cache=True, allocates=False)
def elastic_hessian_cs(pos, theta, cth, sth, l0, voronoi, ea, ga, ei, band, scale):
    """:func:`elastic_hessian_band` with the directors given; writes each entry directly."""
    n_el = theta.shape[0]
    for e in range(n_el):
        c = cth[e]
        s = sth[e]
        _, _, a, b = element_kinematics(pos, e, c, s)
        ka = ea[e] / l0[e]
        ks = ga[e] / l0[e]
        # local Hessian in (Delta_x, Delta_z, theta)
        hxx = scale * (ka * c * c + ks * s * s)
        hxz = scale * ((ka - ks) * c * s)
        hzz = scale * (ka * s * s + ks * c * c)
        p = (ka - ks) * b
        q = ka * (a - l0[e]) - ks * a
        hxt = scale * (p * c - q * s)
        hzt = scale * (p * s + q * c)
        htt = scale * (-a * q + (ka - ks) * b * b)
        # DOFs x_e, z_e, th_e, x_e+1, z_e+1 at 3e .. 3e+4; Delta = r_{e+1} - r_e
        i = 3 * e
        band[i, 4] += hxx
        band[i, 5] += hxz
        band[i, 6] -= hxt
        band[i, 7] -= hxx
        band[i, 8] -= hxz
        band[i + 1, 3] += hxz
        band[i + 1, 4] += hzz
        band[i + 1, 5] -= hzt
        band[i + 1, 6] -= hxz
        band[i + 1, 7] -= hzz
        band[i + 2, 2] -= hxt
        band[i + 2, 3] -= hzt
        band[i + 2, 4] += htt
        band[i + 2, 5] += hxt
        band[i + 2, 6] += hzt
        band[i + 3, 1] -= hxx
        band[i + 3, 2] -= hxz
        band[i + 3, 3] += hxt
        band[i + 3, 4] += hxx
        band[i + 3, 5] += hxz
        band[i + 4, 0] -= hxz
        band[i + 4, 1] -= hzz
        band[i + 4, 2] += hzt
        band[i + 4, 3] += hxz
        band[i + 4, 4] += hzz
    band[2, 4] += scale * ei[0] / voronoi[0]
    for v in range(1, n_el):
        k = ei[v] / voronoi[v]
        i0 = 3 * (v - 1) + 2
        i1 = 3 * v + 2
        band[i0, 4] += scale * k
        band[i1, 4] += scale * k
        band[i0, 4 + i1 - i0] -= scale * k
        band[i1, 4 + i0 - i1] -= scale * k


@njit(cache=True, allocates=False)
def banded_factor(band):
    """In-place LU of a banded matrix (half-bandwidth 4), no pivoting; multipliers kept below,
    and each pivot's reciprocal in its place on the diagonal (the solve multiplies by it).

    The implicit step's matrix M - h^2 K - h C is dominated by the lumped mass
    diagonal, so elimination without pivoting is stable. A full-width column is
    eliminated with fixed offsets and its pivot row in registers (not re-read from
    ``band``, which the updates write): it is most of an exact implicit step's cost.
    """
    n = band.shape[0]
    for k in range(n):
        inv = 1.0 / band[k, 4]
        band[k, 4] = inv
        if k + 4 < n:  # a full-width column: fixed offsets, the pivot row held in registers
            u = (band[k, 5], band[k, 6], band[k, 7], band[k, 8])
            for d in range(1, 5):
                f = band[k + d, 4 - d] * inv
                band[k + d, 4 - d] = f
                for e in range(1, 5):
                    band[k + d, 4 + e - d] -= f * u[e - 1]
        else:  # the last four columns
            for i in range(k + 1, n):
                f = band[i, 4 + k - i] * inv
                band[i, 4 + k - i] = f
                for j in range(k + 1, n):
                    band[i, 4 + j - i] -= f * band[k, 4 + j - k]


@njit(cache=True, fastmath={"contract"}, allocates=False)
def banded_substitute(band, x):
    """Solve in place with a matrix factored by :func:`banded_factor`.

    Each sweep is a chain of dependent multiply-adds; the four entries ahead of the
    chain are carried in registers (not re-read from ``x``), and multiply-adds may be
    fused, which is what bounds its speed.
    """
    n = band.shape[0]
    if n < 5:
        for k in range(n):
            for i in range(k + 1, n):
                x[i] -= band[i, 4 + k - i] * x[k]
        for k in range(n - 1, -1, -1):
            acc = x[k]
            for j in range(k + 1, n):
                acc -= band[k, 4 + j - k] * x[j]
            x[k] = acc * band[k, 4]
        return
    a0 = x[0]
    a1 = x[1]
    a2 = x[2]
    a3 = x[3]
    for k in range(n - 4):
        a4 = x[k + 4] - band[k + 4, 0] * a0
        a3 -= band[k + 3, 1] * a0
        a2 -= band[k + 2, 2] * a0
        a1 -= band[k + 1, 3] * a0
        x[k] = a0
        a0 = a1
        a1 = a2
        a2 = a3
        a3 = a4
    # the last four rows of L
    a1 -= band[n - 3, 3] * a0
    a2 -= band[n - 2, 2] * a0
    a3 -= band[n - 1, 1] * a0
    a2 -= band[n - 2, 3] * a1
    a3 -= band[n - 1, 2] * a1
    a3 -= band[n - 1, 3] * a2
    # U, from the bottom
    b1 = a3 * band[n - 1, 4]
    b2 = (a2 - band[n - 2, 5] * b1) * band[n - 2, 4]
    b3 = (a1 - band[n - 3, 5] * b2 - band[n - 3, 6] * b1) * band[n - 3, 4]
    b4 = (a0 - band[n - 4, 5] * b3 - band[n - 4, 6] * b2 - band[n - 4, 7] * b1) * band[n - 4, 4]
    x[n - 1] = b1
    x[n - 2] = b2
    x[n - 3] = b3
    x[n - 4] = b4
    for k in range(n - 5, -1, -1):
        b0 = (x[k] - band[k, 8] * b1 - band[k, 7] * b2 - band[k, 6] * b3 - band[k, 5] * b4) * band[k, 4]
        x[k] = b0
        b1 = b2
        b2 = b3
        b3 = b4
        b4 = b0


@njit(cache=True, allocates=False)
def banded_multiply_subtract(band, v, out):
    """out -= band @ v, for a banded matrix in :func:`banded_factor`'s layout (unfactored); the
    interior rows written out, as in the factorisation."""
    n = band.shape[0]
    for d in range(min(4, n)):
        acc = 0.0
        for j in range(0, min(n, d + 5)):
            acc += band[d, 4 + j - d] * v[j]
        out[d] -= acc
    for d in range(4, n - 4):
        out[d] -= (
            band[d, 0] * v[d - 4]
            + band[d, 1] * v[d - 3]
            + band[d, 2] * v[d - 2]
            + band[d, 3] * v[d - 1]
            + band[d, 4] * v[d]
            + band[d, 5] * v[d + 1]
            + band[d, 6] * v[d + 2]
            + band[d, 7] * v[d + 3]
            + band[d, 8] * v[d + 4]
        )
    for d in range(max(4, n - 4), n):
        acc = 0.0
        for j in range(d - 4, n):
            acc += band[d, 4 + j - d] * v[j]
        out[d] -= acc


@njit(cache=True, allocates=False)
def paper_elastic_forces(
    pos, theta, cth, sth, theta_root, rest_pos, l0, voronoi, dtheta0, ea, ei, k_restore, force, moment
) -> float:
    """The paper's leg model, eqs. (2)-(4), plus its virtual restoring spring (for comparison).

    Axial force E A eps along each element's *own angle* (eq. 3, R_i^T [f_ax, 0]) and
    bending from relative angles only (eq. 4): angles never feel positions (there is
    no shear coupling), so the shape is held by a spring k_r pulling every node
    towards its rest position, translated with the root. Returns the root moment.
    """
    n_el = theta.shape[0]
    for e in range(n_el):
        dx, dz, _, _ = element_kinematics(pos, e, cth[e], sth[e])
        f_ax = ea[e] * (np.sqrt(dx * dx + dz * dz) - l0[e]) / l0[e]
        force[e, 0] += cth[e] * f_ax
        force[e, 1] += sth[e] * f_ax
        force[e + 1, 0] -= cth[e] * f_ax
        force[e + 1, 1] -= sth[e] * f_ax
    m_root = bending_moments(theta, theta_root, voronoi, dtheta0, ei, moment)
    shift_s = pos[0, 0] - rest_pos[0, 0]
    shift_z = pos[0, 1] - rest_pos[0, 1]
    for i in range(1, pos.shape[0]):
        force[i, 0] -= k_restore * (pos[i, 0] - rest_pos[i, 0] - shift_s)
        force[i, 1] -= k_restore * (pos[i, 1] - rest_pos[i, 1] - shift_z)
    return m_root
