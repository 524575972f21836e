"""Gyro calibration from the rotations between static poses, no turntable (imu_tk, Tedaldi 2014).

The unit rests in a dozen or more poses and is turned by hand between them. Integrating the
candidate-calibrated gyro across each motion must carry the first pose's gravity-up direction
(accelerometer frame) onto the next pose's. The model is raw = K·ω + b with ω in the calibrated
accelerometer frame and K = diag(k)·(I + M) full: three scale factors k (output units per rad/s)
and six small angles m_ij = M[i, j] (gyro axis i leaning toward accelerometer axis j), so the
gyro-to-accelerometer rotation is estimated too. Calibrated rate = K⁻¹(raw − b).

- ``integrate(omega, t, spans) -> (m, 4)``: quaternions (scipy's scalar-last order) of C, the
  rotation from the body at t[i1] to the body at t[i0] for each inclusive span [i0, i1]:
  v_start = C · v_end for a vector fixed in the world. Each step is the exact exponential of
  φ = ∫ω + h²/12 · ω_j × ω_{j+1}: the integral from the cubic Hermite rule (trapezoid minus
  h²/12 times the change of dω/dt, which comes from a three-point stencil on the samples), the
  cross product the two-sample coning correction, exact to O(h⁵) for a smooth rate. Global
  error O(h⁴). The steps of all spans are padded into one (m, L) array and composed by a
  pairwise (tree) reduction: log2(L) vectorised quaternion products, no loop over samples.
- ``solve_rotations(Motions, RotationStart, RotationNoise, ...) -> Calibration`` (the data, the
  start and what whitens the residuals, each a typed value; ``solve_gyro_rotations(t, raw, spans,
  up_start, up_end, *, K0, b0, ...)`` builds them from plain arrays). Residuals, 2 per motion in rad: Cᵀ·up_start − up_end in a tangent basis (a, b) at up_end.
  Its theta is bias_x..z, scale_x..z, m_xy, m_xz, m_yx, m_yz, m_zx, m_zy (FULL_PARAM_NAMES),
  ``covariance`` theta's; a bias held at b0 (``diagnostics.held``) has bias_sigma as its σ,
  uncorrelated with the rest. The search and its covariance run over the estimated
  parameters only. The noise model whitens the residuals: up_sigma (rad, a
  scalar, (m,) or (m, 2) for [start, end]: each pose direction's 1σ per tangent component),
  rate_noise (angle random walk, rad/√s: adds rate_noise²·duration), and bias_sigma (output
  units, scalar or (3,)): with the bias fixed at b0 its error is common to every motion and is
  propagated as a full covariance G·Σb·Gᵀ (G = ∂r/∂b, i.e. marginalised); with the bias
  estimated it is a prior b0 ± bias_sigma. A pose shared by consecutive motions (the same up
  vector passed as one motion's end and the next one's start) correlates their residuals; the
  whitening includes it. Without up_sigma and rate_noise the covariance is scaled by the
  residual variance (``scaled_by_residuals``), as it is when χ² is implausible (Birge).

The search runs in coordinates whitened by the Jacobian at K0, b0 (as in norm.py), so raw counts
(k ≈ 1877, b ≈ 32768) and SI outputs converge alike. Every Jacobian of the rotations is the exact
one of its integration (``_Steps.jacobian``: the per-step right Jacobian of the exponential,
carried to each span's end by walking the composition's tree back down), about three
integrations' work for all twelve parameters where differences took one integration per
parameter; the polish's, whose residuals are the exact integration's, takes two steps as one with
their coning (``_POLISH_GROUP``: half the work, within 1e-6 of the exact Jacobian); the search (which only finds
the way to the polish) integrates coarsely, four steps as one with the coning between them
(``_Steps.coarse``): its residuals and their exact Jacobians, which that integration gives
too, at about a quarter of the exact Jacobian's work; its optimum is within a few hundredths of
a σ of the exact one, so the polish makes one exact Jacobian. Not modelled: Earth rate
(≤ 2e-4 rad over a 3 s motion: below consumer MEMS noise, not below a tactical gyro's; a caller
that knows the latitude can pass its horizontal part as ``motion_variance``) and bias drift.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.special import chdtrc  # χ² survival function; scipy.stats would cost ~0.4 s to import
from scipy.linalg import lapack

from fieldcal.calibration import ROTATION_METHOD, Calibration, SolverDiagnostics
from fieldcal.model import ANGULAR_RATE, FULL_PARAM_NAMES, k_from_terms, terms_from_k
from fieldcal.solvers.norm import CalibrationError
from fieldcal.solvers.semiseparable import BlockSemiseparable

BIAS_NAMES = FULL_PARAM_NAMES[:3]
METHODS = ("lsq", "powell")
_MOTION_MARGIN = 2  # motions beyond ceil(n_params / 2): some scatter to judge the fit by
_GEOMETRY_RATIO = 1e-3  # smallest / largest singular value of the Jacobian in natural units
_DEGENERATE_FRACTION = 0.01  # σ above this fraction of a parameter's natural unit: undetermined
_GEOMETRY_MARGIN = 10.0  # a coarse Jacobian this near _GEOMETRY_RATIO: the geometry told by the exact one


def _cross(a, b):
    # Faster than np.cross on many short vectors.
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _qmul(p, q):
    """Hamilton product of quaternions stored component-first, (4, ...) [x, y, z, w] (scalar
    last): the rotation matrix of p·q is R(p)·R(q). Summed in place, term by term."""
    px, py, pz, pw = p
    qx, qy, qz, qw = q
    out = np.empty(p.shape)
    x, y, z, w = out
    np.multiply(pw, qx, out=x)
    x += qw * px
    x += py * qz
    x -= pz * qy
    np.multiply(pw, qy, out=y)
    y += qw * py
    y += pz * qx
    y -= px * qz
    np.multiply(pw, qz, out=z)
    z += qw * pz
    z += px * qy
    z -= py * qx
    np.multiply(pw, qw, out=w)
    w -= px * qx
    w -= py * qy
    w -= pz * qz
    return out


def _bit_reversed(n: int) -> np.ndarray:
    """The bit-reversal permutation of range(n), n a power of two."""
    bits = n.bit_length() - 1
    i = np.arange(n)
    out = np.zeros_like(i)
    for b in range(bits):  # (log2 n passes, each over the whole array)
        out |= ((i >> b) & 1) << (bits - 1 - b)
    return out if bits else i


def _compose(q):
    """(4, ..., P, g) -> (4, ..., g): the product of each group's P quaternions in time order,
    stored in bit-reversed order (P a power of two), so that each of the log2(P) passes multiplies
    the first half by the second: element i of the first half is always the step just before
    element i of the second. The groups are the last axis, so each half is one contiguous run of
    memory per leading index (a short strided inner axis would cost numpy several times more)."""
    while q.shape[-2] > 1:
        half = q.shape[-2] // 2
        q = _qmul(q[..., :half, :], q[..., half:, :])
    return q[..., 0, :]


def _rotate_back(q, v):
    """Cᵀ·v for each row (C the rotation of quaternion q)."""
    qv, qw = -q[..., :3], q[..., 3:]
    t = 2.0 * _cross(qv, v)
    return v + qw * t + _cross(qv, t)


def _rate_slopes(values, offset, t, wide, rates):
    """(3, k - 2) dω/dt at samples wide[1:-1] from the quadratic through three neighbours
    (one-sided at the recording's ends): ``rates`` (3, k) are values[wide] − offset, and where
    wide[i - 1], wide[i], wide[i + 1] are not consecutive (between spans) the slope is not used."""
    n = len(t)
    idx = np.clip(wide[1:-1], 0, n - 1)
    c = np.clip(idx, 1, n - 2)
    tm, t0, tp, x = t[c - 1], t[c], t[c + 1], t[idx]
    wm = (2 * x - t0 - tp) / ((tm - t0) * (tm - tp))
    w0 = (2 * x - tm - tp) / ((t0 - tm) * (t0 - tp))
    wp = (2 * x - tm - t0) / ((tp - tm) * (tp - t0))
    vm, v0, vp = rates[:, :-2], rates[:, 1:-1], rates[:, 2:]
    ends = np.flatnonzero(c != idx)  # the first or last sample: its stencil is one-sided
    if len(ends):
        vm, v0, vp = vm.copy(), v0.copy(), vp.copy()
        vm[:, ends], v0[:, ends], vp[:, ends] = ((values[c[ends] + d] - offset).T for d in (-1, 0, 1))
    return wm * vm + w0 * v0 + wp * vp


def _compose_levels(q):
    """As ``_compose`` for one array (4, P, g), keeping every level: [q, pairs, ..., (4, 1, g)]."""
    levels = [q]
    while q.shape[-2] > 1:
        half = q.shape[-2] // 2
        q = _qmul(q[:, :half], q[:, half:])
        levels.append(q)
    return levels


_CONJUGATE = np.array([-1.0, -1.0, -1.0, 1.0])[:, None, None]


def _after(levels, top):
    """Walk ``_compose_levels`` back down: from the (4, 1, g) quaternions of what follows each
    root, the (4, P, g) ones of what follows each leaf, as rotations carried back to the leaf:
    a right child is followed by what follows its parent, a left child by that after its right
    sibling, so its quaternion is the parent's times the sibling's conjugate."""
    s = top
    for children in levels[-2::-1]:
        half = children.shape[1] // 2
        below = np.empty(children.shape)
        below[:, :half] = _qmul(s, children[:, half:] * _CONJUGATE)
        below[:, half:] = s
        s = below
    return s


def _matrix(q):
    """(3, 3, ...) rotation matrices of quaternions (4, ...) [x, y, z, w]."""
    x, y, z, w = 2.0 * q
    x2, y2, z2 = 0.5 * x, 0.5 * y, 0.5 * z
    xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x2, y * y2, z * z2, x * y2, x * z2, y * z2, w * x2, w * y2, w * z2
    R = np.empty((3, 3) + x.shape)
    np.subtract(1.0 - yy, zz, out=R[0, 0])
    np.subtract(xy, wz, out=R[0, 1])
    np.add(xz, wy, out=R[0, 2])
    np.add(xy, wz, out=R[1, 0])
    np.subtract(1.0 - xx, zz, out=R[1, 1])
    np.subtract(yz, wx, out=R[1, 2])
    np.subtract(xz, wy, out=R[2, 0])
    np.add(yz, wx, out=R[2, 1])
    np.subtract(1.0 - xx, yy, out=R[2, 2])
    return R


def _right_jacobians(phi, angle, sinc, cos):
    """(3, 3, ...) right Jacobians of the exponential at rotation vectors phi (3, ...), given
    their angles θ, sin(θ/2)/θ and cos(θ/2): J_r(φ) = I − c1·[φ]× + c2·[φ]×², with
    c1 = (1 − cos θ)/θ² = 2·sinc² and c2 = (θ − sin θ)/θ³."""
    c1 = 2.0 * sinc * sinc
    c2 = (1.0 - 2.0 * sinc * cos) / np.maximum(angle * angle, 1e-300)
    J = np.empty((3, 3) + angle.shape)
    scaled = c2 * phi
    J[0, 0], J[1, 1], J[2, 2] = 1.0 + scaled * phi - c2 * angle * angle  # [φ]×² = φφᵀ − θ²·I
    for a, b, c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):  # [φ]×[a, b] = −φ_c, [φ]×[b, a] = φ_c
        square, cross = scaled[a] * phi[b], c1 * phi[c]
        np.add(square, cross, out=J[a, b])
        np.subtract(square, cross, out=J[b, a])
    return J


def _unit(q: np.ndarray) -> np.ndarray:
    """(4, ...) quaternions scaled to unit norm: a long composition's rounding moves the norm."""
    return q / np.sqrt(np.sum(q * q, axis=0))


def _weights(A, delta_b):
    """(10, 3): a step's rotation vector is this matrix's transpose times its 10 terms (see
    _Steps) for calibrated rates A·(v − δb)."""
    coning = np.linalg.det(A) * np.linalg.inv(A)  # det(A)·K, applied to row vectors
    bias_cross = np.array([[0.0, -delta_b[2], delta_b[1]], [delta_b[2], 0.0, -delta_b[0]],
                           [-delta_b[1], delta_b[0], 0.0]])  # row·this = row × δb
    return np.vstack([A.T, coning, bias_cross @ coning, -(A @ delta_b)[None]])


def _skews(v):
    """(p, 3, 3) matrices X with row·X = row × v, for v (p, 3)."""
    X = np.zeros(v.shape[:-1] + (3, 3))
    X[..., 0, 1], X[..., 0, 2], X[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return X - np.swapaxes(X, -1, -2)


def _weight_derivatives(A, delta_b, dK, d_delta_b):
    """(p, 10, 3): the derivatives of _weights(A, δb) along p directions (dK, dδb) of K = A⁻¹ and
    δb: dA = −A·dK·A, d(det A·K) = det A·(dK − tr(dK·A)·K)."""
    K, det = np.linalg.inv(A), np.linalg.det(A)
    dA = -A @ dK @ A
    coning = det * K
    d_coning = det * (dK - np.einsum("pij,ji->p", dK, A)[:, None, None] * K)
    bias_cross = _skews(np.asarray(delta_b, dtype=float))
    d_bias = _skews(d_delta_b) @ coning + bias_cross @ d_coning
    d_rate = -(dA @ delta_b + d_delta_b @ A.T)
    return np.concatenate([np.swapaxes(dA, 1, 2), d_coning, d_bias, d_rate[:, None]], axis=1)


_BLOCK = 64  # steps composed per block: a span is padded to whole blocks, not to the longest span


def _span_terms(out, values, t, i0, lengths, blocks, offset) -> None:
    """The integration terms (see _Steps) of consecutive spans [i0, i0 + length] into ``out``
    (10, _BLOCK, their blocks), padding steps zero (the identity rotation). Made in time order
    over the samples read (shifted slices, no gathers) and placed once at the steps' positions."""
    n = len(t)
    # Each sample of each span once (span by span, i0..i1) with its slope, offset taken off;
    # a step j reads sample j's row and the next. Read with one more sample each side (the
    # slopes' stencils): consecutive samples, so each stencil is three shifted slices.
    read = lengths + 3
    first_read = np.cumsum(read) - read
    wide = np.arange(read.sum()) - np.repeat(first_read - i0 + 1, read)  # i0 - 1 .. i1 + 1
    clipped = np.clip(wide, 0, n - 1)
    rates = np.ascontiguousarray((values[clipped] - offset).T)  # (3, read)
    table = np.vstack([rates[:, 1:-1], _rate_slopes(values, offset, t, wide, rates)])  # column c: wide[c + 1]
    # Every pair of neighbouring columns as a step: those that straddle two spans are made and
    # not placed (three a span).
    step0, step1 = table[:, :-1], table[:, 1:]
    times = t[clipped]
    h = times[2:-1] - times[1:-2]
    v0, v1 = step0[:3], step1[:3]
    w = h * h / 12.0
    padded = np.empty((10, len(h) + 1))  # (10, columns) in time order, and a zero column: the padding's
    padded[:, -1] = 0.0
    terms = padded[:, :-1]
    # Cubic Hermite rule: trapezoid minus h²/12 times the change of dω/dt over the step.
    np.subtract(h / 2 * (v0 + v1), w * (step1[3:] - step0[3:]), out=terms[0:3])
    terms[3:6] = w * _cross(v0.T, v1.T).T
    np.multiply(w, v1 - v0, out=terms[6:9])
    terms[9] = h
    # Step k of span s: column first_read[s] + k of the table; block first[s] + k // _BLOCK, at
    # the bit-reversed position of k % _BLOCK in it (see _compose).
    span = np.repeat(np.arange(len(i0)), lengths)
    k = np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    column = first_read[span] + k
    if np.any(h[column] <= 0):
        raise ValueError("t must increase within every span")
    first = np.cumsum(blocks) - blocks
    # Each place's column (the zero one where a span is padded), then all of them gathered in
    # place order: a scatter of the (10, steps) terms to their places cost three times as much.
    source = np.full(out[0].size, len(h))
    source[_bit_reversed(_BLOCK)[k % _BLOCK] * out.shape[2] + first[span] + k // _BLOCK] = column
    places = out.view()
    places.shape = (len(out), -1)  # out's own memory (an error, not a copy, were it not one block)
    # mode "clip" (every index is in range): with the default "raise", numpy gathers into a
    # buffer and copies it to ``out`` (so that an error leaves it untouched), ~2.5× the cost.
    np.take(padded, source, axis=1, out=places, mode="clip")


def _paired(terms: np.ndarray) -> np.ndarray:
    """(10, P, ...) the terms of steps at P positions in bit-reversed time order (see _compose)
    -> (10, P/2, ...): each two neighbouring steps as one, positions p and p + P/2 (the first
    the earlier), again in bit-reversed order. Their terms summed, and the coning between them:
    the product of their exponentials is that of φ_a + φ_b + ½·φ_a × φ_b to second order
    (Baker–Campbell–Hausdorff), and with φ = A·(V − h·δb) (V the integral of v)
    φ_a × φ_b = det(A)·Kᵀ·(V_a × V_b + (h_a·V_b − h_b·V_a) × δb): the coning terms' and the
    bias cross terms' form, so it adds to theirs. Pairing pairs keeps every cross product of a
    group's steps, earlier × later: ½·Σ_{i<j} φ_i × φ_j."""
    half = terms.shape[1] // 2
    a, b = terms[:, :half], terms[:, half:]
    out = a + b
    (ax, ay, az), (bx, by, bz) = a[0:3], b[0:3]
    out[3] += 0.5 * (ay * bz - az * by)
    out[4] += 0.5 * (az * bx - ax * bz)
    out[5] += 0.5 * (ax * by - ay * bx)
    out[6:9] += 0.5 * (a[9] * b[0:3] - b[9] * a[0:3])
    return out


_KEPT_GROUP = 4  # steps taken as one: the coarse level kept (the search's)


class _PairedParts:
    """A coarse copy's parts (``_Steps.parts``, one a span group) made from the steps' own when
    read, ``group`` steps as one (see ``_paired``): only the last one read is kept."""

    def __init__(self, parts: "list[np.ndarray] | _PairedParts", group: int):
        self.parts, self.group = parts, group
        self._last: tuple[int, np.ndarray] = (-1, np.zeros(0))

    def __len__(self) -> int:
        return len(self.parts)

    def __getitem__(self, index: int) -> np.ndarray:
        if self._last[0] != index:
            terms, size = self.parts[index], 1
            while size < self.group:
                terms, size = _paired(terms), 2 * size
            self._last = index, terms
        return self._last[1]

    def __iter__(self):
        return (self[index] for index in range(len(self)))
_SPAN_GROUP_BLOCKS = 512  # blocks whose compositions are made at once (~4 MiB, see _Steps._forward)
_JACOBIAN_BLOCKS = 32  # blocks whose (3, 3, steps) matrices a Jacobian makes at once (~0.15 MiB each)


class _Steps:
    """The steps of some spans, each span padded with identity steps to whole blocks of _BLOCK.
    A span's blocks are composed first (all blocks of all spans at once), then each span's
    blocks. The increments are linear in the rate, so for ω = A·(v − δb) (A = K⁻¹) each
    evaluation is one product of per-step sums of v, made once:
    ∫ω = A·(∫v − h·δb) and ω_j × ω_{j+1} = det(A)·Kᵀ·(v_j × v_{j+1} + (v_{j+1} − v_j) × δb).
    ``offset`` is taken off the rates where they are read (raw counts keep their precision and
    the samples are not copied)."""

    def __init__(self, values, t, spans, offset=None):
        t = np.asarray(t, dtype=float)
        spans = np.asarray(spans, dtype=int).reshape(-1, 2)
        n = len(t)
        if np.shape(values) != (n, 3) or n < 3:
            raise ValueError(f"rates must be (n, 3) with n >= 3 matching t, got {np.shape(values)}")
        i0, i1 = spans[:, 0], spans[:, 1]
        if len(spans) == 0 or np.any(i0 < 0) or np.any(i1 >= n) or np.any(i1 <= i0):
            raise ValueError(f"spans must be [i0, i1] with 0 <= i0 < i1 < {n}")
        lengths = i1 - i0
        blocks = -(-lengths // _BLOCK)
        values = np.asarray(values, dtype=float)
        self.offset = offset = np.zeros(3) if offset is None else np.asarray(offset, dtype=float).copy()
        # Spans integrated together by _forward and jacobian: consecutive ones, about
        # _SPAN_GROUP_BLOCKS blocks in all (one longer span alone).
        group = np.cumsum(blocks) // _SPAN_GROUP_BLOCKS
        cuts = np.r_[0, np.flatnonzero(np.diff(group)) + 1, len(spans)]
        self.span_groups = list(zip(cuts[:-1].tolist(), cuts[1:].tolist()))
        # Stored position-major, (_BLOCK, blocks): position p of every block, then p + 1; within
        # a block the positions are the steps in bit-reversed order (see _compose). One array a
        # group of spans (``parts``), made one at a time: the dozen per-step temporaries then stay
        # small (made for all spans at once they took ~4 times the terms' own memory), and each
        # integration reads a group's terms in place (as slices of one array they were copied).
        parts = []
        for g0, g1 in self.span_groups:
            part = np.empty((10, _BLOCK, int(blocks[g0:g1].sum())))
            _span_terms(part, values, t, i0[g0:g1], lengths[g0:g1], blocks[g0:g1], offset)
            parts.append(part)
        self.parts: list[np.ndarray] | _PairedParts = parts  # the pairs' of a coarse copy made when read
        self._place(blocks)
        self.duration = t[i1] - t[i0]
        self.block = _BLOCK  # steps per block (fewer in a ``coarse`` copy)
        self._groups: dict = {}  # the grouped terms by group, the coarse copies
        self._last = None  # (key, the quaternions) of the last K⁻¹, δb integrated

    def _place(self, blocks: np.ndarray) -> None:
        """Where each span's ``blocks`` are (numbered span by span) and how they compose."""
        first = np.cumsum(blocks) - blocks
        # Each span's blocks, padded to a power of two with an identity block, bit-reversed.
        size = 1 << int(blocks.max() - 1).bit_length()
        slot = np.arange(size)
        gather = np.where(slot < blocks[:, None], first[:, None] + slot, blocks.sum())
        self.gather = gather[:, _bit_reversed(size)].T.copy()  # (size, m), as _compose reads it
        self.first_block = first  # each span's first block (they are numbered span by span)
        self.n_blocks = int(blocks.sum())

    def subset(self, rows: np.ndarray) -> "_Steps":
        """The steps of spans ``rows`` (increasing) alone, as made anew from the samples (the
        same terms, span groups and places) but with their blocks copied out of these: for a
        sixth of the spans, a seventh of that work."""
        rows = np.asarray(rows, dtype=int)
        blocks = np.diff(np.r_[self.first_block, self.n_blocks])
        starts = self.first_block[[g0 for g0, _ in self.span_groups]]  # each part's first block
        group = np.cumsum(blocks[rows]) // _SPAN_GROUP_BLOCKS  # as __init__ groups them
        cuts = np.r_[0, np.flatnonzero(np.diff(group)) + 1, len(rows)]
        steps = copy.copy(self)
        steps.parts = []
        for c0, c1 in zip(cuts[:-1], cuts[1:]):
            mine = rows[c0:c1]
            index = np.repeat(self.first_block[mine] - (np.cumsum(blocks[mine]) - blocks[mine]), blocks[mine]) \
                + np.arange(blocks[mine].sum())  # their blocks, numbered as here
            owner = np.searchsorted(starts, index, side="right") - 1
            pieces = [self.parts[o][:, :, index[owner == o] - starts[o]] for o in np.unique(owner)]
            steps.parts.append(np.concatenate(pieces, axis=2) if len(pieces) > 1 else pieces[0])
        steps.span_groups = list(zip(cuts[:-1].tolist(), cuts[1:].tolist()))
        steps._place(blocks[rows])
        steps.duration = self.duration[rows]
        steps._groups, steps._last = {}, None
        return steps

    def coarse(self, group: int) -> "_Steps":
        """These spans with ``group`` consecutive steps taken as one (their terms summed, see
        ``quaternions``): blocks of _BLOCK // group steps, the spans' blocks as here, so that
        ``jacobian`` and ``quaternions`` work alike on a group-th of the steps. Made once for
        _KEPT_GROUP steps and more (the search's); fewer (the polish's pairs, asked once a
        solve) each time, their terms made span group by span group as they are read (made
        whole, they were 11 MiB more at the solve's peak on imu_tk's recording joined 16×)."""
        key = ("coarse", group)
        if key in self._groups:
            return self._groups[key]
        steps = copy.copy(self)
        steps.block, steps._groups, steps._last = _BLOCK // group, {}, None
        if group >= _KEPT_GROUP:
            steps.parts = self._grouped_parts(group)
            self._groups[key] = steps
        else:
            steps.parts = _PairedParts(self.parts, group)
        return steps

    @property
    def terms(self) -> np.ndarray:
        """(10, steps) all the terms, position-major over all blocks (a new array)."""
        return np.concatenate(list(self.parts), axis=2).reshape(len(self.parts[0]), -1)

    def _grouped(self, group: int) -> np.ndarray:
        """The terms of ``group`` consecutive steps as one step, (10, steps / group)
        position-major over all blocks: their terms summed, and the coning between them too
        (see ``_paired``), made by pairing neighbours log2(group) times; the level of
        _KEPT_GROUP steps is kept (the search's; the scan's, twice as coarse, is made from it)."""
        if group in self._groups:
            return self._groups[group]
        c = len(self.parts[0])
        known = max((g for g in self._groups if isinstance(g, int) and group % g == 0), default=1)
        made = [self._groups[known].reshape(c, self.block // known, -1)] if known > 1 else self.parts
        size = known
        while size < group:
            made, size = [_paired(terms) for terms in made], 2 * size
            if size == _KEPT_GROUP or size == group:
                whole = np.concatenate(made, axis=2) if len(made) > 1 else made[0]
                if size == _KEPT_GROUP:
                    self._groups[size] = whole.reshape(c, -1)
                made = [whole]
        return made[0].reshape(c, -1)

    def _grouped_parts(self, group: int) -> list[np.ndarray]:
        """``_grouped`` by the span groups' blocks: views, no copy (a coarse copy's parts)."""
        whole = self._grouped(group).reshape(len(self.parts[0]), self.block // group, -1)
        ends = np.cumsum([part.shape[-1] for part in self.parts])
        return [whole[:, :, end - part.shape[-1]:end] for part, end in zip(self.parts, ends)]

    def quaternions(self, K_inv, delta_b, group: int = 1):
        """(m, 4) quaternions of each span's rotation, scalar last. ``group`` (a power of two up
        to _BLOCK): so many consecutive steps taken as one, their increments summed (a coarse
        integration that leaves out the coning between them: for a scan, not a solve)."""
        if group == 1:
            return self._forward(K_inv, delta_b)
        return self.compose(_weights(np.asarray(K_inv, dtype=float), delta_b).T @ self._grouped(group), group)

    def _levels(self, A, delta_b, index: int):
        """The composition of span group ``index``, spans g0..g1 - 1 (consecutive; their blocks
        b0..b1 - 1, its part of the terms): (phi,
        sin(θ/2)/θ, cos(θ/2), θ of their steps, the composition's levels inside the blocks and
        over each span's blocks, those spans' columns of ``gather`` numbered from b0 (the
        identity block: b1 - b0))."""
        g0, g1 = self.span_groups[index]
        blocks = self.first_block[g0:g1 + 1] if g1 < len(self.first_block) else \
            np.r_[self.first_block[g0:g1], self.n_blocks]
        b0, b1 = int(blocks[0]), int(blocks[-1])
        terms = self.parts[index].reshape(len(self.parts[index]), -1)
        phi = _weights(A, delta_b).T @ terms
        angle = np.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
        sinc = np.sin(0.5 * angle) / np.maximum(angle, 1e-300)  # sin(θ/2)/θ
        cos = np.cos(0.5 * angle)
        inner = _compose_levels(np.concatenate([phi * sinc, cos[None]]).reshape(4, self.block, -1))
        top = np.concatenate([inner[-1][:, 0], [[0.0], [0.0], [0.0], [1.0]]], axis=1)  # and identity
        gather = self.gather[:, g0:g1]
        local = np.where(gather == self.n_blocks, b1 - b0, gather - b0)
        return phi, angle, sinc, cos, inner, _compose_levels(top[:, local]), local

    def _forward(self, K_inv, delta_b):
        """(m, 4) quaternions as ``quaternions``, a group of spans at a time (their compositions
        made and dropped: on imu_tk's recording joined 16× they took 32 MiB made for all spans
        at once); the last one kept, as the same point is often asked again."""
        A, delta_b = np.asarray(K_inv, dtype=float), np.asarray(delta_b, dtype=float)
        key = A.tobytes() + delta_b.tobytes()
        if self._last is None or self._last[0] != key:
            q = np.concatenate([self._levels(A, delta_b, index)[5][-1][:, 0]
                                for index in range(len(self.span_groups))], axis=1)
            self._last = key, _unit(q).T
        return self._last[1]

    def jacobian(self, K_inv, delta_b, dK, d_delta_b):
        """(m, 4) quaternions as ``quaternions`` and (m, 3, p) their derivatives along p
        directions of (K, δb), dK (p, 3, 3) and d_delta_b (p, 3): δψ with C(x + dx) = C·exp(δψ×)
        to first order (rad per unit of dx). Exact (no differencing): each step's rotation
        vector φ_j moves by dW_jᵀ·terms_j, its rotation by J_r(φ_j) times that (the right
        Jacobian of the exponential), and a change on step j reaches the span's end rotated by
        S_jᵀ, S_j the product of the steps after j. The S_j come from the products the
        composition made, walked back down its tree (a left child is followed by its right
        sibling): about one more composition's work for all p directions. A group of spans at a
        time (see ``_forward``): the compositions of all spans are never held at once."""
        A = np.asarray(K_inv, dtype=float)
        delta_b = np.asarray(delta_b, dtype=float)
        quaternions, sums = [], []
        for index in range(len(self.span_groups)):
            q, T = self._group_jacobian(A, delta_b, index)
            quaternions.append(q)
            sums.append(T)
        q = np.concatenate(quaternions, axis=1)
        q = _unit(q).T
        T = np.concatenate(sums).reshape(len(q), 3, 3, -1)
        dW = _weight_derivatives(A, delta_b, np.asarray(dK, dtype=float), np.asarray(d_delta_b, dtype=float))
        return q, np.einsum("sabc,kcb->sak", T, dW)

    def _group_jacobian(self, A, delta_b, index: int):
        """(4, spans) quaternions of spans g0..g1 - 1 (not normalised) and (spans, 9, 10) the
        sums of B = S·J_r against each step's terms (see ``jacobian``)."""
        g0, g1 = self.span_groups[index]
        phi, angle, sinc, cos, inner, outer, local = self._levels(A, delta_b, index)
        q = outer[-1][:, 0]
        # Back down: each node's S (as a quaternion), the product of everything after it.
        after = np.empty((4, inner[-1].shape[-1] + 1))
        identity = np.array([0.0, 0.0, 0.0, 1.0])
        after[:, local] = _after(outer, np.broadcast_to(identity[:, None, None], (4, 1, q.shape[1])))
        after = _after(inner, after[:, None, :-1])  # (4, self.block, blocks)
        # B = S·J_r, summed against each step's terms per block: per_block[k, ab, c] = Σ_j B_j[a, b]·t_j[c].
        # Made a few blocks at a time: the (3, 3, steps) matrices are then never all held at once.
        n_blocks = after.shape[-1]
        b0 = int(self.first_block[g0])
        block = self.block
        terms = self.parts[index]
        c = len(terms)
        shaped = [x.reshape(x.shape[:-1] + (block, n_blocks)) for x in (phi, angle, sinc, cos)]
        per_block = np.empty((n_blocks, 9, c))
        chunk = _JACOBIAN_BLOCKS * _BLOCK // block  # as many steps at once in a coarse copy
        for lo in range(0, n_blocks, chunk):
            part = np.s_[..., lo:lo + chunk]
            B = np.einsum("ab...,bc...->ac...", _matrix(after[part]),
                          _right_jacobians(*(x[part] for x in shaped)), optimize=False)
            per_block[part[1]] = np.matmul(B.reshape(9, block, -1).transpose(2, 0, 1), terms[part].transpose(2, 1, 0))
        return q, np.add.reduceat(per_block, self.first_block[g0:g1] - b0, axis=0)

    def compose(self, phi, group: int = 1):
        """(..., m, 4) quaternions of each span's rotation from its steps' rotation vectors phi
        (..., 3, steps), each step the exact exponential of its phi (see ``quaternions``)."""
        angle = np.sqrt(phi[..., 0, :] ** 2 + phi[..., 1, :] ** 2 + phi[..., 2, :] ** 2)
        half = 0.5 * angle
        q = np.empty((4,) + angle.shape)
        # sin(θ/2)/θ times φ; at θ = 0 (the padding) φ = 0 and any finite factor gives 0.
        np.multiply(np.moveaxis(phi, -2, 0), np.sin(half) / np.maximum(angle, 1e-300), out=q[:3])
        np.cos(half, out=q[3])
        q = _compose(q.reshape(q.shape[:-1] + (_BLOCK // group, -1)))  # (4, ..., blocks)
        identity = np.broadcast_to(np.array([0.0, 0.0, 0.0, 1.0]).reshape((4,) + (1,) * (q.ndim - 1)),
                                   q.shape[:-1] + (1,))
        q = _compose(np.concatenate([q, identity], axis=-1)[..., self.gather])  # (4, ..., m)
        return np.moveaxis(_unit(q), 0, -1)


def integrate(omega, t, spans) -> np.ndarray:
    """(m, 4) quaternions of C (v_start = C·v_end) over each inclusive span of calibrated rates."""
    return _Steps(omega, t, spans).quaternions(np.eye(3), np.zeros(3))


_SCAN_GROUP = 8  # steps taken as one by the coarse scan (0.08 s at 100 Hz)
_SCAN_BATCH = 8  # candidate scales integrated at once (their temporaries: a few MiB)
_SCAN_SAMPLE = 6  # every so many motions bound every scale's misfit from below (see scan_scale)
_SCAN_BOUNDED = 2  # scales integrated at once over all motions, in the order of their bounds
_SCAN_MARGIN = 100.0  # a neighbour this many times the coarse error off the best: no contender


def scan_scale(t, raw, spans, up_start, up_end, b0, scales, motions: Motions | None = None) -> float:
    """The k of ``scales`` (sorted, a few dozen) whose K = k·I best carries every motion's start
    direction onto its end (least sum of squared misfits): a raw-count gyro's sensitivity, the
    start of its solve. The best k by a coarse integration (eight steps as one, their coning
    kept), then the best of it and those of its two neighbours whose coarse misfit is not far
    beyond its own, judged by how far its coarse misfit is from its exact one (see below), by
    the exact integration.

    The misfit is a sum over the motions of squares, so every _SCAN_SAMPLE-th motion's share is
    a lower bound of it: all k are integrated over those motions, and over all motions only in
    the order of their bounds until the next bound exceeds the least misfit found. A k left out
    cannot be the best, so the choice is the full scan's.

    ``motions``: the same t, raw and spans as a Motions whose steps the solve will use (made
    here, offset by b0, unless already made with another offset)."""
    scales = np.asarray(scales, dtype=float)
    spans = np.asarray(spans, dtype=int).reshape(-1, 2)
    mine = motions is not None and motions.t is t and motions.raw is raw and np.array_equal(motions.spans, spans)
    steps = motions.steps(b0) if mine and motions is not None else None
    if steps is None or not np.array_equal(steps.offset, b0):
        steps = _Steps(raw, t, spans, offset=b0)
    up_s, up_e = np.asarray(up_start, dtype=float), np.asarray(up_end, dtype=float)

    grouped: dict = {}  # the coarse terms of each steps (made once here: they are not kept)

    def coarse(steps, k, rows=slice(None)):
        # K⁻¹ = I/k, no bias change: a step's phi is ∫v/k + coning/k², for a batch of k at once.
        if id(steps) not in grouped:
            grouped[id(steps)] = steps._grouped(_SCAN_GROUP)
        terms = grouped[id(steps)]
        q = steps.compose(terms[None, 0:3] / k[:, None, None] + terms[None, 3:6] / k[:, None, None] ** 2,
                          _SCAN_GROUP)
        return np.sum((_rotate_back(q, up_s[rows]) - up_e[rows]) ** 2, axis=(1, 2))

    def batches(index):
        return np.array_split(index, -(-len(index) // _SCAN_BATCH))

    rows = np.arange(0, len(spans), _SCAN_SAMPLE)
    sample = steps.subset(rows)
    # A batch of scales at a time, as below (all at once took 32 MiB on imu_tk's recording joined 16×).
    bound = np.concatenate([coarse(sample, scales[i], rows) for i in batches(np.arange(len(scales)))])
    misfits = np.full(len(scales), np.inf)
    order = np.argsort(bound, kind="stable")
    for start in range(0, len(order), _SCAN_BOUNDED):
        if bound[order[start]] > np.min(misfits) * (1 + 1e-9):  # the rest too: none can be the best
            break
        batch = order[start:start + _SCAN_BOUNDED]
        misfits[batch] = coarse(steps, scales[batch])
    if not np.all(np.isfinite(bound)) or np.any(np.isnan(misfits)):  # no bound: every k
        misfits = np.concatenate([coarse(steps, scales[i]) for i in batches(np.arange(len(scales)))])
    best = int(np.argmin(misfits))

    def exact(steps, k, rows=slice(None)):
        return float(np.sum((_rotate_back(steps.quaternions(np.eye(3) / k, np.zeros(3)), up_s[rows]) - up_e[rows])
                            ** 2))

    # The best's exact misfit tells how far the coarse integration is off (relative); a
    # neighbour's moves by about as much (its remainder grows as k⁻³: 2.4 times a grid step
    # down), so only a neighbour whose coarse misfit, or its bound, is within _SCAN_MARGIN times
    # that of the best's is integrated exactly too (on imu_tk's recording, 1x and 16x, the
    # neighbours' misfits are 19 % and more above the best's, the coarse error 4e-4).
    exact_best = exact(steps, scales[best])
    error = abs(exact_best / misfits[best] - 1)
    found = {best: exact_best}
    for i in range(max(best - 1, 0), min(best + 2, len(scales))):
        coarse_misfit = misfits[i] if np.isfinite(misfits[i]) else bound[i]  # not integrated: its bound
        if i != best and coarse_misfit <= misfits[best] * (1 + _SCAN_MARGIN * error):
            found[i] = exact(steps, scales[i])
    return float(scales[min(found, key=lambda i: (found[i], i))])


def _tangent_bases(up):
    """(m, 3, 2): two orthonormal columns perpendicular to each unit vector."""
    helper = np.eye(3)[np.argmin(np.abs(up), axis=1)]
    a = _cross(up, helper)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    return np.stack([a, _cross(up, a)], axis=2)


def _chained_up_covariance(E, C, up_covariance):
    """Residual covariance from a full covariance of the chained poses' up vectors: motion i
    joins pose i to pose i+1, so r_i moves by E_iᵀ·C_iᵀ·δup_i − E_iᵀ·δup_{i+1}. The map is
    block-bidiagonal: sums of elementwise products with its 2×3 blocks, never a dense
    2m×3(m+1) product (O(m²), not O(m³))."""
    m = len(E)
    slabs = np.asarray(up_covariance, dtype=float).reshape(m + 1, 3, 3 * (m + 1))
    start = np.swapaxes(E, 1, 2) @ np.swapaxes(C, 1, 2)  # (m, 2, 3): E_iᵀ·C_iᵀ
    end = -np.swapaxes(E, 1, 2)  # (m, 2, 3): −E_iᵀ
    rows = sum(start[:, :, b, None] * slabs[:-1, None, b, :] + end[:, :, b, None] * slabs[1:, None, b, :]
               for b in range(3)).reshape(2 * m, m + 1, 3)  # A·U
    return sum(rows[:, :-1, c, None] * start[None, :, :, c] + rows[:, 1:, c, None] * end[None, :, :, c]
               for c in range(3)).reshape(2 * m, 2 * m)  # (A·U)·Aᵀ


def _residual_covariance(E, C, shared, up_sigma, rate_noise, duration, motion_variance=None, out=None):
    """(2m, 2m) covariance of the rotation residuals from the direction and rate noise (into
    ``out``, zeros of that shape, when given): ``_independent_parts`` placed."""
    m = len(E)
    cov = np.zeros((2 * m, 2 * m)) if out is None else out
    diagonal, above = _independent_parts(E, C, shared, up_sigma, rate_noise, duration, motion_variance)
    cov[np.arange(2 * m), np.arange(2 * m)] += diagonal
    for i in np.flatnonzero(np.any(above != 0, axis=(1, 2))):
        cov[2 * i:2 * i + 2, 2 * i + 2:2 * i + 4] = above[i]
        cov[2 * i + 2:2 * i + 4, 2 * i:2 * i + 2] = above[i].T
    return cov


def _independent_parts(E, C, shared, up_sigma, rate_noise, duration, motion_variance=None):
    """The residual covariance from the direction and rate noise: its diagonal (2m,) and the
    blocks (m − 1, 2, 2) above it, (i, i+1).

    A direction error δ at the start pose reaches the residual as E_endᵀ·Cᵀ·δ, one at the end
    as −E_endᵀ·δ; both are isotropic in the tangent plane. A pose shared by motions i and i+1
    correlates them by −σ²·E_iᵀ·C_{i+1}·E_{i+1}."""
    m = len(E)
    diagonal, above = np.zeros(2 * m), np.zeros((max(m - 1, 0), 2, 2))
    if up_sigma is not None:
        s = np.asarray(up_sigma, dtype=float)
        s = np.broadcast_to(s[:, None] if s.ndim == 1 else s, (m, 2))
        diagonal += np.repeat(s[:, 0] ** 2 + s[:, 1] ** 2, 2)
        i = np.flatnonzero(shared)
        above[i] = -(s[i, 1] * s[i + 1, 0])[:, None, None] * (np.swapaxes(E[i], 1, 2) @ C[i + 1] @ E[i + 1])
    if rate_noise is not None:  # angle random walk, independent between motions
        diagonal += np.repeat(rate_noise**2 * duration, 2)
    if motion_variance is not None:  # e.g. the horizontal Earth rate, heading unknown
        diagonal += np.repeat(np.broadcast_to(np.asarray(motion_variance, float), (m,)), 2)
    return diagonal, above


def _jacobian(fun, x, steps, central=True, f0=None):
    """Central (else forward, from ``f0`` = fun(x) if known) differences, one column per parameter."""
    if not central:
        f0 = fun(x) if f0 is None else f0
        return np.column_stack([(fun(x + e) - f0) / h for e, h in zip(np.diag(steps), steps, strict=True)])
    return np.column_stack([(fun(x + e) - fun(x - e)) / (2 * h)
                            for e, h in zip(np.diag(steps), steps, strict=True)])


@dataclass(frozen=True)
class Motions:
    """The motions between static poses, the data of a rotation solve: t (n,) s, raw (n, 3) gyro
    output, spans (m, 2) inclusive samples of each motion (last of pose i .. first of pose i+1),
    up_start, up_end (m, 3) unit gravity-up in the accelerometer frame at its two poses."""

    t: np.ndarray
    raw: np.ndarray
    spans: np.ndarray
    up_start: np.ndarray
    up_end: np.ndarray
    # The steps, once made: not an init field, so dataclasses.replace starts a new cache.
    _made: dict = field(default_factory=dict, init=False, compare=False, repr=False)

    def steps(self, offset) -> _Steps:
        """The motions' integration steps, made once (with the first caller's ``offset``: any
        value near the bias keeps raw counts' precision; a later caller's bias is a change δb)."""
        if "steps" not in self._made:
            self._made["steps"] = _Steps(self.raw, self.t, self.spans, offset=offset)
        return self._made["steps"]

    @classmethod
    def of(cls, t, raw, spans, up_start, up_end) -> "Motions":
        """From plain arrays; the up vectors need not be unit length."""
        spans = np.asarray(spans, dtype=int).reshape(-1, 2)
        m = len(spans)
        up_s, up_e = (np.asarray(u, dtype=float).reshape(m, 3) for u in (up_start, up_end))
        up_s, up_e = (u / np.linalg.norm(u, axis=1, keepdims=True) for u in (up_s, up_e))
        return cls(t, raw, spans, up_s, up_e)

    @property
    def shared(self) -> np.ndarray:
        """(m - 1,) bool: motions i and i+1 around one pose (the same up vector)."""
        return np.all(self.up_end[:-1] == self.up_start[1:], axis=1)


@dataclass(frozen=True)
class RotationStart:
    """Where the search starts: K0 a dominant-diagonal 3×3 (``of`` takes a scalar or (3,) too),
    b0 the bias, held there unless ``estimate_bias``."""

    K0: np.ndarray
    b0: np.ndarray
    estimate_bias: bool = False

    @classmethod
    def of(cls, K0, b0, estimate_bias=False) -> "RotationStart":
        """K0: nominal scalar, (3,) or dominant-diagonal 3×3."""
        K0 = np.diag(np.broadcast_to(np.asarray(K0, dtype=float), 3)) if np.ndim(K0) < 2 else \
            np.asarray(K0, dtype=float)
        k0 = np.diag(K0)
        if K0.shape != (3, 3) or np.any(np.abs(k0) <= np.abs(K0 - np.diag(k0)).sum(axis=1)):
            raise ValueError("K0 must be a 3x3 matrix with a dominant diagonal (map the axes first)")
        return cls(K0, np.broadcast_to(np.asarray(b0, dtype=float), 3).copy(), bool(estimate_bias))


@dataclass(frozen=True)
class RotationNoise:
    """What whitens the residuals (see the module docstring): up_sigma or up_covariance for the
    pose directions, rate_noise (rad/√s), motion_variance (rad²), bias_sigma (output units).
    None of them: the covariance is scaled by the residuals' scatter."""

    bias_sigma: object = None
    up_sigma: object = None
    rate_noise: float | None = None
    motion_variance: object = None
    up_covariance: np.ndarray | None = None

    @property
    def given(self) -> bool:
        return any(x is not None for x in (self.up_sigma, self.rate_noise, self.motion_variance,
                                           self.up_covariance))


class _Residuals:
    """The residuals as functions of theta (bias if estimated, scale terms, angles)."""

    def __init__(self, motions: Motions, start: RotationStart, bias_sigma, extra: Callable | None):
        self.start, self.extra = start, extra
        self.estimate_bias = start.estimate_bias
        self.nb = 3 if start.estimate_bias else 0
        self.names = FULL_PARAM_NAMES if start.estimate_bias else FULL_PARAM_NAMES[3:]
        self.theta0 = np.r_[start.b0[:self.nb], np.concatenate(terms_from_k(start.K0))]
        self.prior = start.estimate_bias and bias_sigma is not None
        self.sigma_b = np.broadcast_to(np.asarray(bias_sigma if bias_sigma is not None else 1.0, float), 3)
        self.motions = motions
        # The motion samples only, offset by b0 (or by what the scale scan that made them used)
        # so that raw counts keep their precision.
        self.steps = motions.steps(start.b0)
        self.E = _tangent_bases(motions.up_end)

    def unpack(self, theta):
        nb = self.nb
        bias = theta[:3] if self.estimate_bias else self.start.b0
        return bias, np.linalg.inv(k_from_terms(theta[nb:nb + 3], theta[nb + 3:]))

    def quaternions(self, theta):
        """(m, 4) the motions' rotations at theta (the integration ``rotations`` makes, kept)."""
        b, K_inv = self.unpack(theta)
        return self.steps.quaternions(K_inv, b - self.steps.offset)

    def rotations(self, theta, bias=None, group: int = 1):
        """2 per motion, rad: Cᵀ·up_start − up_end in the end pose's tangent basis (bias: instead
        of theta's; ``group``: so many steps as one, as ``jacobian``'s)."""
        b, K_inv = self.unpack(theta)
        steps = self.steps.coarse(group) if group > 1 else self.steps
        q = steps.quaternions(K_inv, (b if bias is None else bias) - self.steps.offset)
        return np.einsum("mi,mik->mk", _rotate_back(q, self.motions.up_start) - self.motions.up_end,
                         self.E).ravel()

    def jacobian(self, theta, bias=None, group: int = 1):
        """(rotations as ``rotations``, their (2m, 12) Jacobian over bias_x..z, scale_x..z and
        the six angles, whether the bias is estimated or held, exact (see _Steps.jacobian), and
        the motions' quaternions). ``group`` > 1: all three of the coarse integration's
        (``_Steps.coarse(group)``): the search's and the polish's Jacobians."""
        nb = self.nb
        b, K_inv = self.unpack(theta)
        scale, angles = theta[nb:nb + 3], theta[nb + 3:]
        dK = np.zeros((12, 3, 3))
        dK[3:6] = [k_from_terms(e, angles) for e in np.eye(3)]  # K is linear in each group
        dK[6:] = [k_from_terms(scale, e) - np.diag(scale) for e in np.eye(6)]
        steps = self.steps.coarse(group) if group > 1 else self.steps
        q, D = steps.jacobian(K_inv, (b if bias is None else bias) - self.steps.offset, dK, np.eye(12, 3))
        turned = _rotate_back(q, self.motions.up_start)
        r = np.einsum("mi,mik->mk", turned - self.motions.up_end, self.E).ravel()
        # Cᵀ·u moves by (Cᵀ·u) × δψ when C becomes C·exp(δψ×).
        moved = _cross(turned[:, None, :], np.swapaxes(D, 1, 2))  # (m, 12, 3)
        return r, np.einsum("mpi,mik->mkp", moved, self.E).reshape(len(r), 12), q

    def side(self, theta):
        """The bias prior's equations (when estimated with a σ) and the extra ones, whitened."""
        b, K_inv = self.unpack(theta)
        parts = [(b - self.start.b0) / self.sigma_b] if self.prior else []
        if self.extra is not None:
            parts.append(np.atleast_1d(np.asarray(self.extra(K_inv, b.copy()), dtype=float)))
        return np.concatenate(parts) if parts else np.zeros(0)


def _check_geometry(model: _Residuals, J_start, natural, name, exact: Callable | None = None) -> np.ndarray:
    """The rotation residuals' Jacobian at the start (natural units: it scales the search) from
    ``J_start`` (model.jacobian's at theta0, maybe the coarse one's); CalibrationError when the
    motions leave some parameter (nearly) without effect. ``exact``: the exact Jacobian at theta0,
    asked for when the coarse one's geometry is near the bound or past it, so that the verdict
    and the parameters it names are the exact Jacobian's."""
    J_rot = J_start[:, 3 - model.nb:] * natural
    sv, V = np.linalg.svd(J_rot, full_matrices=False)[1:]
    if exact is not None and sv[-1] < _GEOMETRY_MARGIN * _GEOMETRY_RATIO * sv[0]:
        return _check_geometry(model, exact(), natural, name)
    weak = sv < _GEOMETRY_RATIO * sv[0]
    if np.any(weak):
        loose = [model.names[i] for i in np.unique(np.argmax(np.abs(V[weak]), axis=1))]
        raise CalibrationError(
            f"{name}: the motions do not span enough rotation axes: {', '.join(loose)} barely "
            f"change the rotations (condition number {sv[0] / max(sv[-1], 1e-300):.3g}); "
            "turn the unit about other axes")
    return J_rot


def _whitening(model: _Residuals, J_start, q_start, noise: RotationNoise, n_side: int, name: str):
    """Whitening of [rotation residuals, side residuals] (``whiten @ r``): the side ones come
    whitened, but a fixed bias's error is common to all of them, so it is marginalised over the
    joint vector (``J_start``, ``q_start``: model.jacobian's at theta0; its first columns are
    ∂r/∂b). The covariance's Cholesky factor by its parts in O(m) (``semiseparable``) where the
    pose directions' covariance comes by its parts (or not at all), else dense."""
    if not noise.given:
        return None
    from scipy.spatial.transform import Rotation  # only a weighted solve pays for scipy.spatial's import

    C = Rotation.from_quat(q_start).as_matrix()
    G = _bias_map(model, J_start, noise) if noise.bias_sigma is not None and not model.start.estimate_bias else None
    parts = getattr(noise.up_covariance, "chained_parts", None)
    chained = None if parts is None else parts(model.E, C)
    if noise.up_covariance is None or (chained is not None and not isinstance(chained.windows, np.ndarray)):
        structured = _structured_covariance(model, C, noise, chained, G, n_side)
        try:
            return structured.factor()
        except ValueError:
            raise CalibrationError(f"{name}: the residual covariance is not positive definite") from None
    return _dense_whitening(model, C, noise, G, n_side, name)


def _bias_map(model: _Residuals, J_start, noise: RotationNoise) -> np.ndarray:
    """∂[rotations, side residuals]/∂b at the start times the held bias's σ: its error, common to
    every residual, is their covariance's low-rank part G·Σb·Gᵀ."""
    G = J_start[:, :3]
    model_extra, start = model.extra, model.start
    if model_extra is not None:
        K_inv0 = model.unpack(model.theta0)[1]

        def extra(b):
            return np.atleast_1d(np.asarray(model_extra(K_inv0, b.copy()), dtype=float))
        G = np.vstack([G, _jacobian(extra, start.b0, 1e-6 * np.abs(np.diag(start.K0)))])
    return G * model.sigma_b


def _structured_covariance(model: _Residuals, C, noise: RotationNoise, chained, G, n_side: int):
    """The residual covariance (as ``_dense_whitening`` makes it) as a ``BlockSemiseparable``:
    one 2×2 block per motion, the side residuals a last block; the pose directions' covariance
    from ``chained`` (``ChainedPoses``, or None), the held bias's error ``G`` (rows scaled by
    its σ, or None) a low-rank part of every block."""
    m, E = len(model.motions.spans), model.E
    if chained is None:
        diagonal, sub = np.zeros((m, 2, 2)), np.zeros((m - 1, 2, 2))
        left, right, decay, low = np.zeros((m, 2, 0)), np.zeros((m, 0, 2)), np.ones((m, 0)), np.zeros((m, 2, 0))
    else:
        diagonal, sub, left, right, decay, low = chained.blocks()
    # _residual_covariance's parts: each motion's own (diagonal) and a shared pose's (up_sigma).
    independent, above = _independent_parts(E, C, model.motions.shared, noise.up_sigma, noise.rate_noise,
                                            model.steps.duration, noise.motion_variance)
    diagonal[:, [0, 1], [0, 1]] += independent.reshape(m, 2)
    sub += np.swapaxes(above, 1, 2)
    tail_diagonal, tail_low = np.eye(n_side), np.zeros((n_side, low.shape[2]))
    if G is not None:
        bias_low = G[:2 * m].reshape(m, 2, 3)
        diagonal += bias_low @ np.swapaxes(bias_low, 1, 2)
        low = np.concatenate([low, bias_low], axis=2)
        tail_low = np.hstack([tail_low, G[2 * m:]])
        tail_diagonal = tail_diagonal + G[2 * m:] @ G[2 * m:].T
    return BlockSemiseparable(diagonal, sub, left, right, decay, low, tail_diagonal, tail_low)


def _dense_whitening(model: _Residuals, C, noise: RotationNoise, G, n_side: int, name: str) -> np.ndarray:
    """L⁻¹ of the dense covariance: for a dense up_covariance (and as the structured one's check)."""
    m, steps = len(model.motions.spans), model.steps
    # One dense matrix, made, factored and inverted in place: on a long recording (2m ≈ 1300 on
    # imu_tk's joined 16×) each more copy is another 13 MiB at the solve's peak of memory.
    full = np.zeros((2 * m + n_side,) * 2)
    cov = full[:2 * m, :2 * m]
    _residual_covariance(model.E, C, model.motions.shared, noise.up_sigma, noise.rate_noise,
                         steps.duration, noise.motion_variance, out=cov)
    if noise.up_covariance is not None:  # a matrix, or its parts (one with a chained method)
        chained = getattr(noise.up_covariance, "chained", None)
        if chained is not None and n_side == 0:
            chained(model.E, C, out=full)
        else:
            cov += chained(model.E, C) if chained is not None else _chained_up_covariance(
                model.E, C, np.asarray(noise.up_covariance, dtype=float))
    full[range(2 * m, 2 * m + n_side), range(2 * m, 2 * m + n_side)] = 1.0
    if G is not None:
        full += G @ G.T
    # LAPACK reads the C-ordered symmetric matrix as its transpose (the same matrix): the upper
    # factor U there (UᵀU = cov) is L = Uᵀ here, and U's inverse there L⁻¹ here.
    U, info = lapack.dpotrf(full.T, lower=0, clean=1, overwrite_a=1)
    if info != 0:
        raise CalibrationError(f"{name}: the residual covariance is not positive definite")
    inverse, info = lapack.dtrtri(U, lower=0, overwrite_c=1)
    if info != 0:
        raise CalibrationError(f"{name}: the residual covariance is not positive definite")
    return inverse.T  # L⁻¹, by the triangular inverse: a third of a general one's work


_STEP_TOL = 1e-6  # σ (of the parameters): a polishing step this short ends the solve
_SEARCH_TOL = 1e-2  # σ: a search step this short hands over to the polish (see _POLISH_DONE)
_MAX_ITERATIONS = 100
_FAR = 30.0  # σ: after a longer step the Jacobian is made afresh, after a shorter one updated
_SEARCH_GROUP = 4  # steps taken as one by the search's Jacobians (_Steps.coarse; 1: exact ones)
# Steps taken as one by the polish's Jacobians, whose residuals are the exact integration's: two
# with their coning are within 1e-6 of the exact Jacobian (imu_tk's recording, 1x and 16x), so
# the optimum they lead to is the exact one's within 1e-6 σ, for half the work; 1: exact ones.
_POLISH_GROUP = 2


def _broyden_gauss_newton(fun, jac, p: int, Q: np.ndarray) -> tuple[np.ndarray, int]:
    """Minimise ‖fun(z)‖² from z = 0, where fun's Jacobian at 0 is Q (orthonormal columns, so z
    is in σ units): Gauss–Newton steps on a Jacobian made afresh (``jac(z)``) after a
    step longer than _FAR σ and otherwise kept current by Broyden's rank-one updates (no
    evaluations of their own), each step halved until it lowers the cost. (z, iterations) once
    a step is below _SEARCH_TOL σ: the polish takes it from there.

    Where a long step would land, the Jacobian is made before fun is asked (a ``jac`` that
    integrates can keep the residuals it gives for fun; solve_rotations' search asks the
    coarse integration's, about a quarter of an exact Jacobian's work, so a step that fails
    costs little more than its evaluation)."""
    z, r, J, fresh = np.zeros(p), fun(np.zeros(p)), Q.copy(), True
    cost = float(r @ r)
    for iteration in range(1, _MAX_ITERATIONS + 1):
        dz = -np.linalg.lstsq(J, r, rcond=None)[0]
        if np.linalg.norm(dz) < _SEARCH_TOL:
            return z, iteration
        for _ in range(8):
            J_there = jac(z + dz) if np.linalg.norm(dz) > _FAR else None
            r_new = fun(z + dz)
            if float(r_new @ r_new) <= cost:
                break
            dz = dz / 2
        else:
            if fresh:  # no step along the true gradient lowers the cost: at the optimum
                return z, iteration
            J = jac(z)
            fresh = True
            continue
        r_old = r
        z, r, cost, fresh = z + dz, r_new, float(r_new @ r_new), False
        if J_there is not None:  # far from the optimum: the curvature has changed much
            J = J_there
            fresh = True
        else:
            J = J + np.outer(r - r_old - J @ dz, dz) / float(dz @ dz)
    return z, _MAX_ITERATIONS


def _search(whitened, jacobian, theta0, to_theta, Q, method):
    """(theta, converged, message, iterations) of the search in whitened coordinates z."""
    p = len(theta0)
    if method == "powell":
        from scipy import optimize  # only this search pays for it

        res = optimize.minimize(lambda z: float(np.sum(whitened(theta0 + to_theta @ z) ** 2)),
                                np.zeros(p), method="Powell",
                                options={"direc": np.eye(p), "xtol": 1e-4, "ftol": 1e-13,
                                         "maxfev": 20000})
        return theta0 + to_theta @ res.x, bool(res.success), str(res.message), int(res.nit)
    z, iterations = _broyden_gauss_newton(lambda z: whitened(theta0 + to_theta @ z),
                                          lambda z: jacobian(theta0 + to_theta @ z) @ to_theta, p, Q)
    converged = iterations < _MAX_ITERATIONS
    message = (f"Gauss-Newton (Broyden): steps below {_SEARCH_TOL:g} sigma after {iterations} iterations"
               if converged else f"Gauss-Newton (Broyden): no convergence in {iterations} iterations")
    return theta0 + to_theta @ z, converged, message, iterations


_POLISH_DONE = 0.1  # σ: after a longer polishing step the Jacobian is made afresh


def _polish(whitened, jacobian, theta, natural):
    """(theta, the whitened residuals and their Jacobian in natural units): Gauss–Newton steps on
    Jacobians made afresh (``jacobian(theta)``, the covariance's), so that the optimum does not
    depend on the search's approximate Jacobian, until a step is below _STEP_TOL σ. The Jacobian is made afresh
    after a step longer than _POLISH_DONE σ (or one that fails); shorter ones reuse it (chord
    steps, one evaluation each). The Jacobian returned is the last one made. After a longer step
    it is made before the residuals are asked, as in _broyden_gauss_newton (its integration
    gives them)."""
    J, fresh = jacobian(theta) * natural, True
    r = whitened(theta)
    for _ in range(20):
        d = -np.linalg.lstsq(J, r, rcond=None)[0]
        size = np.linalg.norm(J @ d)  # σ: the whitened residuals change by as much
        if size < _STEP_TOL:
            break
        J_there = jacobian(theta + natural * d) * natural if size > _POLISH_DONE else None
        r_new = whitened(theta + natural * d)
        if float(r_new @ r_new) > float(r @ r):
            if fresh:
                break
            J, fresh = jacobian(theta) * natural, True
            continue
        theta, r = theta + natural * d, r_new
        if J_there is not None:
            J, fresh = J_there, True
        else:
            fresh = False
    return theta, r, J


def solve_rotations(motions: Motions, start: RotationStart, noise: RotationNoise = RotationNoise(),
                    extra_residuals: Callable | None = None, method="lsq", name="gyro",
                    output_unit="") -> Calibration:
    """Solve K (and b) from the motions between static poses; see the module docstring and
    :func:`solve_gyro_rotations` for what each input means."""
    if method not in METHODS:
        raise ValueError(f"method: expected one of {', '.join(METHODS)}, got {method!r}")
    m = len(motions.spans)
    if noise.up_covariance is not None and (noise.up_sigma is not None
                                            or np.shape(noise.up_covariance) != (3 * m + 3,) * 2):
        raise ValueError(f"up_covariance: expected a ({3 * m + 3}, {3 * m + 3}) matrix for {m} chained "
                         "motions, and no up_sigma with it")
    if not noise.given and (noise.bias_sigma is not None or extra_residuals is not None):
        raise ValueError("bias_sigma and extra_residuals need up_sigma or rate_noise: the "
                         "rotation residuals must be whitened too")
    p = 12 if start.estimate_bias else 9
    n_side = 3 * bool(start.estimate_bias and noise.bias_sigma is not None)
    if extra_residuals is not None:
        n_side += len(np.atleast_1d(extra_residuals(np.linalg.inv(start.K0), start.b0.copy())))
    need = max(2, math.ceil((p - n_side) / 2) + _MOTION_MARGIN)
    if m < need:
        raise CalibrationError(f"{name}: {m} motions between poses, need at least {need}: "
                               "add more poses")
    model = _Residuals(motions, start, noise.bias_sigma, extra_residuals)
    theta0, nb, names = model.theta0, model.nb, model.names
    k0 = np.diag(start.K0)
    # Natural units: a bias turning the mean motion by 1 rad, relative scale, 1 rad of angle.
    natural = np.r_[np.abs(k0)[:nb] / model.steps.duration.mean(), np.abs(k0), np.ones(6)]
    fd_steps = 1e-7 * natural
    # The search only finds the way: its residuals and Jacobians are the coarse integration's
    # (a quarter of the steps, the coning between them kept; a coarse Jacobian gives the
    # residuals too), the start's as well: they weigh the residuals (the held bias's share
    # G, the poses' rotations C, at the start, not at the optimum) and point the search. The
    # polish's, whose optimum and covariance are the result, are exact.
    coarse = _SEARCH_GROUP
    r_start, J_start, q_start = model.jacobian(theta0, group=coarse)
    J_rot = _check_geometry(model, J_start, natural, name, lambda: model.jacobian(theta0)[1])
    whiten = _whitening(model, J_start, q_start, noise, n_side, name)
    count = [0]
    recent: dict[tuple[int, bytes], tuple[np.ndarray, np.ndarray]] = {}  # (group, theta): (residuals, whitened)

    def evaluated(theta, rotations=None, group=1):
        """The residuals at theta and them whitened (``group`` > 1: the coarse integration's);
        the last few kept, as the search's Jacobians give their residuals and the polish its
        optimum to the result (``rotations``: the rotation residuals at theta when an
        integration has given them already)."""
        key = group, theta.tobytes()
        if key not in recent:
            r = np.r_[model.rotations(theta, group=group) if rotations is None else rotations, model.side(theta)]
            keep(key, r, r if whiten is None else whiten @ r)
        return recent[key]

    def keep(key, r, r_whitened):
        count[0] += 1
        if len(recent) >= 4:
            del recent[next(iter(recent))]
        recent[key] = r, r_whitened

    def whitened(theta):
        return evaluated(theta)[1]

    def whitened_with(theta, rotations, group, J):
        """J (of the residuals at theta) whitened, and the residuals with it, kept as
        evaluated's when they are not yet: one pass of the whitener for both (a pass is a few
        ms on imu_tk's recording joined 16×, most of it its loop over the blocks, whatever the
        columns)."""
        key = group, theta.tobytes()
        if whiten is None or key in recent:
            evaluated(theta, rotations, group)
            return J if whiten is None else whiten @ J
        r = np.r_[rotations, model.side(theta)]
        both = whiten @ np.column_stack([r, J])
        keep(key, r, both[:, 0])
        return both[:, 1:]

    J_side = _jacobian(model.side, theta0, fd_steps) * natural if n_side else np.zeros((0, p))
    # The search starts from the start's Jacobian's residuals.
    J0 = whitened_with(theta0, r_start, coarse, np.vstack([J_rot, J_side]))
    # Search in z, theta = theta0 + natural·R⁻¹z with J0 = QR: locally ‖r‖² ≈ ‖z − z*‖².
    Q, R = np.linalg.qr(J0)
    to_theta = natural[:, None] * np.linalg.inv(R)
    def jacobian(theta, group):
        """Of whitened: the rotations' (those of the integration ``group`` steps as one: the
        search's coarse one, or the polish's pairs), the side residuals' by forward
        differences. The rotations its integration gives are kept as evaluated's."""
        rotations, J, _ = model.jacobian(theta, group=group)
        J = J[:, 3 - nb:]
        if n_side:
            J = np.vstack([J, _jacobian(model.side, theta, fd_steps, central=False)])
        return whitened_with(theta, rotations, group, J)

    theta, converged, message, iterations = _search(lambda theta: evaluated(theta, group=coarse)[1],
                                                    lambda theta: jacobian(theta, coarse),
                                                    theta0, to_theta, Q, method)
    if not converged:
        raise CalibrationError(f"{name}: {method} did not converge ({message})")
    theta, r_w, J = _polish(whitened, lambda theta: jacobian(theta, _POLISH_GROUP), theta, natural)
    evaluations = count[0]
    chi2, dof = float(r_w @ r_w), len(r_w) - p
    sv = np.linalg.svd(J, compute_uv=False)
    try:
        cov_natural = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        raise CalibrationError(f"{name}: the motions do not determine the parameters") from None
    scaled = not noise.given or (dof > 0 and chdtrc(dof, chi2) < 1e-3)
    if scaled:
        if dof <= 0:
            raise CalibrationError(f"{name}: no scatter left to estimate the uncertainty; "
                                   "add poses or give up_sigma/rate_noise")
        cov_natural *= chi2 / dof
    sigma_natural = np.sqrt(np.diag(cov_natural))
    worst = int(np.argmax(sigma_natural))
    if scaled and noise.given and sigma_natural[worst] > _DEGENERATE_FRACTION >= sigma_natural[worst] / math.sqrt(
            chi2 / dof):  # the motions span the axes; the rotations do not fit them
        raise CalibrationError(
            f"{name}: the rotations do not fit the motions: χ²/dof {chi2 / dof:.3g}, {math.sqrt(chi2 / dof):.0f} "
            f"times the noise, leaves {names[worst]} determined only to ±{sigma_natural[worst]:.2g}; likely a "
            "pose that was not still, a wrong map (columns, units, axis order, a triad's sign) or a gap or "
            "jump in time")
    if sigma_natural[worst] > _DEGENERATE_FRACTION:
        raise CalibrationError(f"{name}: the motions do not span enough rotation axes: "
                               f"{names[worst]} is determined only to ±{sigma_natural[worst]:.2g} "
                               "of its scale; turn the unit about other axes")
    bias = model.unpack(theta)[0].copy()
    pose = np.cumsum(np.r_[0, ~motions.shared]) + np.arange(m)  # poses numbered from 0, shared or not
    labels = tuple(f"motion {a + 1}→{a + 2} {c}" for a in pose for c in "ab")
    covariance = np.zeros((len(FULL_PARAM_NAMES),) * 2)
    covariance[3 - nb:, 3 - nb:] = cov_natural * np.outer(natural, natural)
    if not start.estimate_bias:  # held at b0: its σ is the prior's, uncorrelated with the estimates
        covariance[:3, :3] = np.diag(model.sigma_b**2) if noise.bias_sigma is not None else 0.0
    return Calibration(
        name=name, kind=ANGULAR_RATE, output_unit=output_unit or "rad/s", method=ROTATION_METHOD,
        theta=np.r_[bias, theta[nb:]], covariance=covariance, parameter_names=FULL_PARAM_NAMES,
        residuals=evaluated(theta)[0][:2 * m], residual_unit="rad", residual_labels=labels,
        diagnostics=SolverDiagnostics(
            iterations=iterations, evaluations=evaluations, converged=converged,
            message=message, search=method, chi2=chi2, dof=dof,
            scaled_by_residuals=bool(scaled), condition_number=float(sv[0] / sv[-1]),
            held=() if start.estimate_bias else BIAS_NAMES, extra_residuals=evaluated(theta)[0][2 * m:]))


def solve_gyro_rotations(t, raw, spans, up_start, up_end, *, K0, b0, estimate_bias=False,
                         bias_sigma=None, up_sigma=None, rate_noise=None, motion_variance=None,
                         up_covariance=None,
                         extra_residuals: Callable | None = None, method="lsq", name="gyro",
                         output_unit="") -> Calibration:
    """:func:`solve_rotations` from plain arrays.

    t (n,), raw (n, 3) gyro output; spans (m, 2) inclusive sample indices of each motion (last
    sample of pose i .. first of pose i+1); up_start, up_end (m, 3) gravity-up in the
    accelerometer frame at its two poses. K0: nominal scalar, (3,) or dominant-diagonal 3×3;
    b0: the fixed bias (the initial-rest mean), or the start when ``estimate_bias``.
    ``motion_variance`` (rad², scalar or (m,)): more variance per tangent component of each
    motion's residual, independent between motions (an unmodelled rotation such as the
    horizontal Earth rate at an unknown heading). ``up_covariance`` ((3(m+1), 3(m+1))): instead
    of ``up_sigma``, the full covariance of the up vectors of poses 0..m when motion i joins pose
    i to pose i+1 (a chain): errors shared by all poses (the accelerometer calibration's) as well
    as each pose's own.
    ``extra_residuals(K_inv, bias)`` returns whitened residuals appended to the rotations' (e.g.
    turntable rate norms). method: "lsq" (Gauss–Newton in the whitened coordinates, its Jacobian
    updated by Broyden's rule and made afresh after long steps) or "powell" (scipy's); either
    ends with Gauss–Newton steps on the covariance's Jacobian (the rotations' exact, see
    ``_Steps.jacobian``; the extra residuals' by forward differences).
    Raises CalibrationError for too few motions (ceil(n_params / 2) + 2, fewer with extra
    equations) or motions that leave a parameter undetermined.
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {', '.join(METHODS)}, got {method!r}")
    start = RotationStart.of(K0, b0, estimate_bias)
    return solve_rotations(Motions.of(t, raw, spans, up_start, up_end), start,
                           RotationNoise(bias_sigma, up_sigma, rate_noise, motion_variance, up_covariance),
                           extra_residuals, method, name, output_unit)
