"""Dynamic programming over the extension cylinder's state (P-VI Algorithm 1, thesis Alg. 3.3.1).

State x = (extension cylinder position c, velocity v), control u = its acceleration, Euler steps
c' = c + T_s v, v' = v + T_s u (P-VI eqs. 30-31). Backward: J_k(x) = min_u L_k(x, u) + J_{k+1}(x')
with bilinear interpolation of J_{k+1}; every joint position, cylinder velocity and cylinder
acceleration limit is a hard constraint (the papers' large penalty, here an infinite cost capped
at ``INFEASIBLE``). Forward: the stored policy is interpolated from any start state.

The position nodes of each stage span its feasible extension window, so joint-limit edges lie on
nodes (``DpGrid``); a node whose next position falls less than one velocity cell's step past a
window end counts as on it (``_bellman_step``). Both are ours, not P-VI's: P-VI's fixed grid and
conservative interpolation kept the vertical path's optimum 4-5 cells off the edge it rides.

Why it is fast (our reading of the structure of P-VI eqs. 29-31; the paper gives no implementation notes):
- the IK, the cylinder velocities and the u-independent stage costs are evaluated once per state
  (N_c x N_v), not per state and control;
- every cylinder acceleration and force is affine in u (q'' is affine in the extension
  acceleration; the dynamics are linear in q''), with a slope that depends on the position alone
  (J^-1 and M(q)): one evaluation per state at u = 0 and two per position (u = 0, 1 at rest) give
  them for all controls, and the admissible controls of a state form one interval of the control grid;
- c' does not depend on u, so the position interpolation is shared by all controls, and the
  next velocities v + T_s u fall in a window of a few velocity cells.
The numba kernel loops over states in parallel (rows in small chunks: their admissible states
differ) and over the admissible controls only; of those, it evaluates only the samples next to a
breakpoint of the piecewise-linear stage cost and cost-to-go (``_breakpoint_samples``), which finds
the same minimum as all of them. For the LS cost each driving cylinder's pressure is one line in u
over an interval (``_pressure_lines``: driven_pressure is affine in the force on each side), so a
sample costs a few multiplications (the LS cost on P-VI's grid: 25 s -> under 3 s).

The forward pass comes twice: ``forward`` searches the admissible controls at each exact state
(offline planning), ``follow`` interpolates the stored policy in compiled code and checks the
result in one vectorised pass (re-planning on line, under a millisecond).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, parallel_chunksize, prange
from tqdm import tqdm

from hydro_ros.contract.check import DP_GRID_MIN
from hydro_ros.contract.errors import InputError
from hydro_ros.models.crane import STRETCHED_ELBOW, Crane
from hydro_ros.models.crane_hydraulics import cylinder_table, driven_pressure, total_pump_flow
from hydro_ros.planning.costs import Cost, stage_power
from hydro_ros.planning.paths import PathSamples
from hydro_ros.planning.trajectory import ExtensionTrajectory, crane_motion

INFEASIBLE = 1.0e15  # cost-to-go of states with no admissible continuation
_FEASIBLE_BELOW = 1.0e12  # any interpolation weight on an infeasible node shows above this
REST_PENALTY = 1.0e10  # J per m/s of final velocity: far above any path's energy, finite for interpolation
SNAP = 1e-9  # interpolation weights closer than this to 0 or 1 are rounding noise
# the tube of DpGrid.around: +-5 cm of stroke and 5 cm/s beyond the reference's speeds (on the K70M's vertical lines
# positions over 10 cm instead of the window's metres and velocities about 3x finer than the full grid's; the
# certificate's cases were tried at 5, 10 and 20 cm)
TUBE_HALF_WIDTH = 0.05  # [m]
TUBE_VELOCITY_PAD = 0.05  # [m/s]
EDGE_SLACK = 0.999  # velocity cells' step a next position may fall past a window end (_bellman_step)


class InfeasibleStart(InputError):
    """No admissible trajectory from the requested start state."""


@dataclass(frozen=True)
class DpGrid:
    """Extension cylinder position x velocity x acceleration grid (P-VI: 356 x 101 x 151).

    The position nodes of stage k span that stage's feasible extension window (``extension_windows``)
    evenly instead of the whole stroke. Where a joint limit or the reach of the IK cuts the stroke,
    a node sits on the cut: a trajectory may ride a limit (the P-VI vertical path's optimum does)
    without the conservative interpolation seeing an infeasible node within a cell of it. This is
    the purpose of DPM's boundary-line method (Sundstroem, Ambuehl & Guzzella 2010) for a 1-D
    position state; P-VI's fixed grid put the CP optimum 18 % above the direct method's on that path.
    """

    positions: np.ndarray  # (N+1, N_c): the position nodes of each stage
    velocities: np.ndarray
    controls: np.ndarray

    @classmethod
    def for_path(cls, crane: Crane, samples: PathSamples, sizes: tuple[int, int, int]) -> DpGrid:
        n_c, n_v, n_u = grid_sizes(sizes)
        ext = crane.extension
        windows = extension_windows(crane, samples)
        return cls(
            positions=windows[:, :1] + (windows[:, 1:] - windows[:, :1]) * np.linspace(0.0, 1.0, n_c),
            velocities=np.linspace(-ext.velocity_max, ext.velocity_max, n_v),
            controls=np.linspace(-ext.acceleration_max, ext.acceleration_max, n_u),
        )

    @classmethod
    def around(cls, crane: Crane, samples: PathSamples, reference: ExtensionTrajectory, sizes: tuple[int, int, int], *,
               half_width: float = TUBE_HALF_WIDTH, velocity_pad: float = TUBE_VELOCITY_PAD) -> DpGrid:
        """The grid of ``sizes`` narrowed to a tube around ``reference`` (a trajectory that keeps the limits): each stage's
        positions within ``half_width`` of it (and its window), the velocities over its range and rest widened by
        ``velocity_pad``, with a node at rest as the full grid has, the controls over the whole limit. The same node counts,
        finer: where the full grid's discrete problem is worse than a feasible baseline (a vertical line's LS optimum needs
        a finer velocity grid than 356 x 101 x 151 gives over the whole stroke and speed), the DP on the tube around that
        baseline searches its neighbourhood finely, and its answer is still the DP's own."""
        n_c, n_v, n_u = grid_sizes(sizes)
        if not (half_width > 0 and velocity_pad > 0):
            raise InputError(f"DP tube: half width {half_width} m and velocity pad {velocity_pad} m/s must be > 0")
        if len(reference.position) != samples.stages + 1:
            raise ValueError(f"reference of {len(reference.position) - 1} stages, path of {samples.stages}")
        ext = crane.extension
        windows = extension_windows(crane, samples)
        low = np.maximum(windows[:, 0], reference.position - half_width)
        high = np.minimum(windows[:, 1], reference.position + half_width)
        if np.any(high <= low):
            k = int(np.argmax(high <= low))
            raise InputError(f"DP tube: the reference at t = {samples.time[k]:.2f} s ({reference.position[k]:.4f} m) is more than "
                             f"{half_width} m outside the feasible extension window {windows[k].round(4).tolist()} m")
        slowest = max(-ext.velocity_max, min(float(reference.velocity.min()), 0.0) - velocity_pad)
        fastest = min(ext.velocity_max, max(float(reference.velocity.max()), 0.0) + velocity_pad)
        # n_v nodes a whole number of steps from rest: one step wider than the range, so that rest is a node; where that
        # passes a velocity limit (a reference near it) the tube is no narrower than the full grid, whose axis is taken
        step = (fastest - slowest) / (n_v - 2)
        velocities = step * math.floor(slowest / step) + step * np.arange(n_v)
        if velocities[0] < -ext.velocity_max or velocities[-1] > ext.velocity_max:
            velocities = np.linspace(-ext.velocity_max, ext.velocity_max, n_v)
        return cls(
            positions=low[:, None] + (high - low)[:, None] * np.linspace(0.0, 1.0, n_c),
            velocities=velocities,
            controls=np.linspace(-ext.acceleration_max, ext.acceleration_max, n_u),
        )

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.positions.shape[1], len(self.velocities), len(self.controls)


def grid_sizes(sizes: tuple[int, int, int]) -> tuple[int, int, int]:
    """``sizes`` (positions, velocities, controls) as the DP takes them, or refused in one line: at least DP_GRID_MIN
    points per axis, and odd velocity and control counts, so that rest and zero acceleration are nodes of the symmetric
    axes (with an even control count a trajectory cannot cruise, only alternate: on the K70M's vertical path the DP came
    out 6-15 % above a pseudo-inverse even refined, at 50 or 76 controls against 0.1-0.2 % at 31, 51, 75 or 77)."""
    n_c, n_v, n_u = (int(size) for size in sizes)
    if min(n_c, n_v, n_u) < DP_GRID_MIN:
        raise InputError(f"DP grid {tuple(sizes)}: at least {DP_GRID_MIN} points per axis")
    even = {axis: node for axis, node, n in (("velocities", "rest", n_v), ("controls", "zero acceleration", n_u)) if n % 2 == 0}
    if even:
        odd = (n_c, n_v + 1 - n_v % 2, n_u + 1 - n_u % 2)
        raise InputError(f"DP grid {tuple(sizes)}: {' and '.join(even)} need an odd count, so that {' and '.join(even.values())} "
                         f"{'is a node' if len(even) == 1 else 'are nodes'} (e.g. {odd})")
    return n_c, n_v, n_u


EDGE_SCAN = 1025  # extensions scanned per stage for the window's ends (2 mm on the K70M), then bisected


def extension_windows(crane: Crane, samples: PathSamples) -> np.ndarray:
    """(N+1, 2): per path sample, the least and greatest extension at which the IK reaches the tip
    with every joint position within its limits, each end to 1e-12 of the stroke and on its inside.

    A stage where only one scanned extension is feasible keeps the whole stroke: its nodes are all
    infeasible and the DP reports the path infeasible. A sample no extension reaches is refused in one
    line (InputError): out of reach, or reached only with the solved links stretched into a line.
    """
    stroke = crane.extension.stroke_max
    tips = tuple(samples.position[:, i, None] for i in range(samples.position.shape[1]))
    rest = (0.0,) * len(tips)

    def inside(c: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            motion = crane.motion(tips, rest, rest, c, 0.0 * c, 0.0 * c, forces=False)
        return np.broadcast_to(crane.limit_checks(motion)["position"], c.shape)

    scan = np.broadcast_to(np.linspace(0.0, stroke, EDGE_SCAN), (samples.stages + 1, EDGE_SCAN))
    ok = inside(scan)
    if not ok.any(axis=1).all():
        k = int(np.argmin(ok.any(axis=1)))
        solved = " and ".join(crane.solved_names)
        raise InputError(f"tip path at t = {samples.time[k]:.2f} s: the tip {np.round(samples.position[k], 3).tolist()} m is out of reach "
                         f"of {crane.name}: no {crane.extension.name} stroke reaches it with every joint in its range and {solved} "
                         f"bent more than {STRETCHED_ELBOW} rad from a line (a stretched elbow is singular: unbounded joint rates)")
    first = np.argmax(ok, axis=1)
    last = EDGE_SCAN - 1 - np.argmax(ok[:, ::-1], axis=1)
    rows = np.arange(len(scan))
    # bisect between the last point out and the first point in (no-ops where the stroke's end is in)
    low_in, low_out = scan[rows, first], scan[rows, np.maximum(first - 1, 0)]
    high_in, high_out = scan[rows, last], scan[rows, np.minimum(last + 1, EDGE_SCAN - 1)]
    while max(np.max(low_in - low_out), np.max(high_out - high_in)) > 1e-12 * stroke:
        middle = 0.5 * (low_in + low_out)
        now_in = inside(middle[:, None])[:, 0]
        low_in, low_out = np.where(now_in, middle, low_in), np.where(now_in, low_out, middle)
        middle = 0.5 * (high_in + high_out)
        now_in = inside(middle[:, None])[:, 0]
        high_in, high_out = np.where(now_in, middle, high_in), np.where(now_in, high_out, middle)
    degenerate = ~ok.any(axis=1) | (high_in - low_in <= 1e-9 * stroke)
    return np.stack([np.where(degenerate, 0.0, low_in), np.where(degenerate, stroke, high_in)], axis=1)


@dataclass
class StageTerms:
    """What the Bellman step needs of one path sample, on a set of states."""

    admissible: np.ndarray  # joint positions, IK and cylinder velocities within limits
    base_cost: np.ndarray  # u-independent stage power (W or m^2/s^2)
    flow: np.ndarray  # pump flow Q_p (m^3/s)
    acc_offset: np.ndarray  # cylinder accelerations a_i = acc_offset + acc_slope u, (n_cyl, *states)
    acc_slope: np.ndarray  # (n_cyl, *positions): the slopes depend on the position alone
    force_offset: np.ndarray  # cylinder forces F_i = force_offset + force_slope u
    force_slope: np.ndarray
    velocity: np.ndarray  # cylinder velocities (n_cyl, ...)


def stage_terms(crane: Crane, samples: PathSamples, k: int, c: np.ndarray, v: np.ndarray, cost: Cost) -> StageTerms:
    with np.errstate(invalid="ignore"):  # unreachable states carry NaN until masked out
        return _stage_terms(crane, samples, k, c, v, cost)


def _stage_terms(crane: Crane, samples: PathSamples, k: int, c: np.ndarray, v: np.ndarray, cost: Cost) -> StageTerms:
    tip, tip_vel, tip_acc = samples.at(k)
    c, v = np.asarray(c, dtype=float), np.asarray(v, dtype=float)
    shape = np.broadcast_shapes(c.shape, v.shape)
    forces = cost.depends_on_control
    motion = crane.motion(tip, tip_vel, tip_acc, c, v, 0.0, forces=forces)
    # d/du of every cylinder acceleration and force is J^-1 and M(q) at the position alone, so the
    # slopes come from u = 0 and u = 1 at rest on the positions' own shape, not on every velocity
    control = np.array([0.0, 1.0]).reshape((2,) + (1,) * c.ndim)
    unit = crane.motion(tip, tip_vel, tip_acc, c, np.zeros_like(c), control, forces=forces)

    def offsets(values: list[np.ndarray]) -> np.ndarray:
        return np.stack([np.broadcast_to(value, shape) for value in values])

    def slopes(values: list[np.ndarray]) -> np.ndarray:
        return np.stack([np.broadcast_to(value[1] - value[0], c.shape) for value in np.broadcast_arrays(*values, control)[:-1]])

    checks = crane.limit_checks(motion)
    acc, acc_slope = offsets(motion.a), slopes(unit.a)
    velocity = offsets(motion.v)
    admissible = (
        np.broadcast_to(checks["position"] & checks["velocity"], shape)
        & np.isfinite(acc).all(axis=0)
        & np.isfinite(acc_slope).all(axis=0)
    )
    flow = np.broadcast_to(total_pump_flow(crane, motion), shape)
    if forces:
        force_offset, force_slope = offsets(motion.force), slopes(unit.force)
        base_cost = np.zeros(shape)
    else:
        force_offset, force_slope = np.zeros((1, *shape)), np.zeros((1, *c.shape))
        base_cost = np.broadcast_to(stage_power(cost, crane, motion), shape)
    return StageTerms(
        admissible=admissible,
        base_cost=np.where(admissible, base_cost, 0.0),
        flow=np.where(admissible, flow, 0.0),
        acc_offset=np.nan_to_num(acc, copy=False),
        acc_slope=np.nan_to_num(acc_slope, copy=False),
        force_offset=np.nan_to_num(force_offset, copy=False),
        force_slope=np.nan_to_num(force_slope, copy=False),
        velocity=np.nan_to_num(velocity, copy=False),
    )


_MODES = {Cost.LS: 1, Cost.ACTUATOR: 2}


@njit(cache=True)
def _control_window(
    acc_offset: np.ndarray,
    acc_slope: np.ndarray,
    acc_max: np.ndarray,
    v: float,
    v_low: float,
    v_high: float,
    controls: np.ndarray,
    ts: float,
    accel_limits: bool,
) -> tuple[float, float]:
    """The interval of admissible accelerations u of one state (empty when low > high)."""
    low = max(controls[0], (v_low - v) / ts)
    high = min(controls[-1], (v_high - v) / ts)
    if accel_limits:
        for n in range(acc_offset.shape[0]):
            a0 = acc_offset[n]
            slope = acc_slope[n]
            limit = acc_max[n] * (1.0 + 1e-9)
            if abs(slope) < 1e-12:
                if abs(a0) > limit:
                    return 1.0, -1.0
                continue
            u1 = (-limit - a0) / slope
            u2 = (limit - a0) / slope
            low = max(low, min(u1, u2))
            high = min(high, max(u1, u2))
    return low, high


@njit(cache=True)
def _stage_power_at(
    mode: int,
    base_cost: float,
    flow: float,
    force_offset: np.ndarray,
    force_slope: np.ndarray,
    velocity: np.ndarray,
    table: np.ndarray,
    hydraulics: np.ndarray,
    u: float,
) -> float:
    if mode == 0:
        return base_cost
    if mode == 1:
        highest = 0.0
        for n in range(velocity.shape[0]):
            pressure = driven_pressure(
                force_offset[n] + force_slope[n] * u,
                velocity[n],
                table[n, 0],
                table[n, 1],
                table[n, 2],
                hydraulics[0],
                hydraulics[1],
                hydraulics[2],
            )
            highest = max(highest, pressure)
        return (highest + hydraulics[3]) * flow / hydraulics[4]
    total = 0.0
    for n in range(velocity.shape[0]):
        total += max((force_offset[n] + force_slope[n] * u) * velocity[n], 0.0)
    return total


@njit(cache=True)
def _snap(weight: float) -> float:
    """An interpolation weight in [0, 1], rounding noise removed: 1e-15 of an INFEASIBLE node is 1 J."""
    if weight < SNAP:
        return 0.0
    if weight > 1.0 - SNAP:
        return 1.0
    return weight


@njit(cache=True)
def _cost_to_go_at(cost_next: np.ndarray, ic: int, wc: float, y: float) -> float:
    """Bilinear interpolation of J_{k+1} at grid coordinates (ic + wc, y); infeasible nodes count as
    INFEASIBLE, so a state within one cell of a limit is conservatively expensive (never optimistic:
    the forward pass cannot run into a dead end, at the price of DPM's boundary effect near limits)."""
    n_v = cost_next.shape[1]
    jv = min(max(int(math.floor(y)), 0), n_v - 2)
    wv = _snap(y - jv)
    return (1.0 - wc) * ((1.0 - wv) * cost_next[ic, jv] + wv * cost_next[ic, jv + 1]) + wc * (
        (1.0 - wv) * cost_next[ic + 1, jv] + wv * cost_next[ic + 1, jv + 1]
    )


@njit(cache=True)
def _add_samples_around(samples: np.ndarray, count: int, position: float, first: int, last: int) -> int:
    """Append the control samples next to fractional sample index ``position`` (a breakpoint), within [first, last]."""
    if position != position or position < first - 2.0 or position > last + 2.0:  # NaN or far outside
        return count
    for m in range(int(math.floor(position - 1e-9)), int(math.floor(position + 1e-9)) + 2):
        if first <= m <= last:
            samples[count] = m
            count += 1
    return count


@njit(cache=True)
def _breakpoint_samples(
    mode: int,
    first: int,
    last: int,
    y_first: float,
    y_per_control: float,
    u_first: float,
    u_step: float,
    force_offset: np.ndarray,
    force_slope: np.ndarray,
    velocity: np.ndarray,
    pressure_lines: np.ndarray,
    drive_threshold: float,
    samples: np.ndarray,
    lines: np.ndarray,
) -> int:
    """Into ``samples``, the control samples (unordered, may repeat; their count returned) among which the minimum of stage cost + interpolated cost-to-go
    over [first, last] lies: both are piecewise linear in u, so the sum is linear between breakpoints and its
    minimum over the samples sits at a window end or next to a breakpoint. Breakpoints: the next velocity
    nodes (J_{k+1} is linear between them), each cylinder force's zero (a driven chamber switches on or
    off), and for the LS cost each crossing of two cylinders' driven-pressure lines (the max switches).
    A few dozen samples instead of every admissible control (151 on P-VI's grid), the same minimum.
    For the LS cost, ``lines`` receives the driving cylinders' pressure lines, which ``_highest_driven_pressure``
    evaluates at the samples."""
    n = force_offset.shape[0]
    samples[0] = first
    samples[1] = last
    count = 2
    y_last = y_first + (last - first) * y_per_control
    for node in range(int(math.ceil(min(y_first, y_last))), int(math.floor(max(y_first, y_last))) + 1):
        count = _add_samples_around(samples, count, first + (node - y_first) / y_per_control, first, last)
    # for the LS cost, row by row: each driving cylinder's pressure line (offset, slope in u) and the
    # interval of u (low, high) in which its force and velocity have one sign, so that it drives
    drivers = 0
    for c in range(n):
        drives = velocity[c] != 0.0  # the actuator cost: max(F v, 0) kinks where F = 0
        if mode == 1:
            side = 0 if velocity[c] > 0.0 else 1
            gain = pressure_lines[c, side, 1]
            # beyond the drive threshold, and not a single-acting cylinder lowering to tank
            drives = abs(velocity[c]) > drive_threshold and gain != 0.0
            if drives:
                lines[0, drivers] = pressure_lines[c, side, 0] + gain * force_offset[c]
                lines[1, drivers] = gain * force_slope[c]
                lines[2, drivers], lines[3, drivers] = -math.inf, math.inf
                if force_slope[c] * velocity[c] > 0.0:
                    lines[2, drivers] = -force_offset[c] / force_slope[c]
                elif force_slope[c] * velocity[c] < 0.0:
                    lines[3, drivers] = -force_offset[c] / force_slope[c]
                elif force_offset[c] * velocity[c] <= 0.0:
                    drives = False
                if drives:
                    drivers += 1
        if drives and force_slope[c] != 0.0:
            count = _add_samples_around(samples, count, (-force_offset[c] / force_slope[c] - u_first) / u_step, first, last)
    for a in range(drivers):
        for b in range(a + 1, drivers):
            if lines[1, a] != lines[1, b]:
                crossing = (lines[0, b] - lines[0, a]) / (lines[1, a] - lines[1, b])
                # a kink of the max only where both cylinders drive
                if lines[2, a] < crossing < lines[3, a] and lines[2, b] < crossing < lines[3, b]:
                    count = _add_samples_around(samples, count, (crossing - u_first) / u_step, first, last)
    lines[2, drivers:] = math.inf  # no further driving cylinder: an empty interval ends the rows
    return count


@njit(cache=True)
def _highest_driven_pressure(lines: np.ndarray, u: float) -> float:
    """max over cylinders of ``driven_pressure`` at control u, from the rows ``_breakpoint_samples`` wrote."""
    highest = 0.0
    for c in range(lines.shape[1]):
        if lines[2, c] == math.inf:
            break
        if lines[2, c] < u < lines[3, c]:
            highest = max(highest, lines[0, c] + lines[1, c] * u)
    return highest


@njit(parallel=True, cache=True)
def _bellman_step(
    cost_next: np.ndarray,
    positions: np.ndarray,
    next_positions: np.ndarray,
    velocities: np.ndarray,
    controls: np.ndarray,
    ts: float,
    mode: int,
    admissible: np.ndarray,
    base_cost: np.ndarray,
    flow: np.ndarray,
    acc_offset: np.ndarray,
    acc_slope: np.ndarray,
    acc_max: np.ndarray,
    force_offset: np.ndarray,
    force_slope: np.ndarray,
    velocity: np.ndarray,
    table: np.ndarray,
    hydraulics: np.ndarray,
    pressure_lines: np.ndarray,
    accel_limits: bool,
) -> tuple[np.ndarray, np.ndarray]:
    n_c, n_v = admissible.shape
    c_step = next_positions[1] - next_positions[0]
    v_step = velocities[1] - velocities[0]
    u_step = controls[1] - controls[0]
    y_per_control = ts * u_step / v_step  # next-velocity grid cells per control step
    # A node on a moving window end stands for the velocities up to the next velocity node, and those
    # above the end's own velocity stay inside: a next position within the step of one velocity cell
    # past the end counts as on it, so the boundary in velocity is found by interpolation instead of
    # costing a velocity cell of every step (the forward pass checks the exact state, it never leaves).
    # A hair under the cell: a node a whole velocity cell from staying on a fixed end stays outside.
    slack = EDGE_SLACK * ts * v_step / c_step
    cost = np.full((n_c, n_v), INFEASIBLE)
    policy = np.full((n_c, n_v), np.nan, dtype=np.float32)
    capacity = 2 + 3 * (int(abs(y_per_control) * controls.shape[0]) + 2) + 3 * acc_offset.shape[0] * (acc_offset.shape[0] + 1) // 2
    for i in prange(n_c):
        samples = np.empty(capacity, np.int64)  # the breakpoint samples and pressure lines of each state of this row
        lines = np.empty((4, acc_offset.shape[0]))
        row = np.empty(n_v)
        for j in range(n_v):
            if not admissible[i, j]:
                continue
            v = velocities[j]
            x = (positions[i] + ts * v - next_positions[0]) / c_step
            if x < -slack or x > n_c - 1 + slack:
                continue
            x = min(max(x, 0.0), n_c - 1.0)
            ic = min(max(int(math.floor(x)), 0), n_c - 2)
            wc = _snap(x - ic)
            low, high = _control_window(
                acc_offset[:, i, j], acc_slope[:, i, 0], acc_max, v, velocities[0], velocities[-1], controls, ts, accel_limits
            )
            if low > high:
                continue
            first = max(int(math.ceil((low - controls[0]) / u_step - 1e-9)), 0)
            last = min(int(math.floor((high - controls[0]) / u_step + 1e-9)), controls.shape[0] - 1)
            if first > last:
                continue
            y_first = (v + ts * controls[first] - velocities[0]) / v_step
            best = INFEASIBLE
            best_m = -1
            if mode == 0:
                # the stage cost is the same for every control and J_{k+1} is piecewise linear in v':
                # its minimum over the control samples lies next to a velocity node or at a window end
                m = first
                while m <= last:
                    to_go = _cost_to_go_at(cost_next, ic, wc, y_first + (m - first) * y_per_control)
                    if to_go < best:
                        best = to_go
                        best_m = m
                    if m == last:
                        break
                    y = y_first + (m - first) * y_per_control
                    node = math.floor(y + 1e-12) + 1.0  # next velocity node above this sample
                    jump = int(math.floor((node - y_first) / y_per_control + 1e-9)) + first
                    m = min(max(jump, m + 1), last) if jump > m else m + 1
                if best_m >= 0:
                    best += ts * base_cost[i, j]
            else:
                f_offset = force_offset[:, i, j]
                f_slope = force_slope[:, i, 0]
                cyl_velocity = velocity[:, i, j]
                count = _breakpoint_samples(
                    mode, first, last, y_first, y_per_control, controls[0], u_step, f_offset, f_slope, cyl_velocity,
                    pressure_lines, hydraulics[2], samples, lines,
                )
                # J_{k+1} interpolated in position once for the velocity nodes this state's controls reach
                y_low = min(y_first, y_first + (last - first) * y_per_control)
                j_low = min(max(int(math.floor(y_low)), 0), n_v - 2)
                j_high = min(max(int(math.floor(y_low + abs((last - first) * y_per_control))), 0), n_v - 2) + 1
                for jv in range(j_low, j_high + 1):
                    row[jv - j_low] = (1.0 - wc) * cost_next[ic, jv] + wc * cost_next[ic + 1, jv]
                scale = ts * flow[i, j] / hydraulics[4]
                for index in range(count):
                    m = samples[index]
                    u = controls[m]
                    if mode == 1:
                        stage = (_highest_driven_pressure(lines, u) + hydraulics[3]) * scale
                    else:
                        stage = ts * _stage_power_at(mode, 0.0, flow[i, j], f_offset, f_slope, cyl_velocity, table, hydraulics, u)
                    y = y_first + (m - first) * y_per_control
                    jv = min(max(int(math.floor(y)), j_low), j_high - 1)
                    wv = _snap(y - jv)
                    total = stage + (1.0 - wv) * row[jv - j_low] + wv * row[jv + 1 - j_low]
                    if total < best or (total == best and m < best_m):  # of equal costs the smallest control, as in order
                        best = total
                        best_m = m
            if best_m >= 0:
                cost[i, j] = min(best, INFEASIBLE)
                policy[i, j] = controls[best_m]
    return cost, policy


def terminal_cost(crane: Crane, samples: PathSamples, grid: DpGrid) -> np.ndarray:
    """Rest-to-rest end (INFERRED: P-V Section 3.2 omits the final cost, its Section 6.1 sets the final velocities to
    zero): infeasible positions are excluded and a final velocity costs REST_PENALTY per m/s, a finite penalty that
    interpolates linearly to zero at rest."""
    terms = stage_terms(crane, samples, samples.stages, grid.positions[-1][:, None], grid.velocities[None, :], Cost.CP)
    return np.where(terms.admissible, REST_PENALTY * np.abs(grid.velocities)[None, :], INFEASIBLE)


@dataclass
class DpSolution:
    """Cost-to-go and policy tables of one path and cost; ``forward`` starts from any state."""

    crane: Crane
    samples: PathSamples
    grid: DpGrid
    cost: Cost
    acceleration_limits: bool
    cost_to_go: np.ndarray  # (N+1, N_c, N_v), J in J (or the velocity costs' units times s)
    policy: np.ndarray  # (N, N_c, N_v) float32 acceleration, NaN where infeasible

    def forward(self, start_position: float, start_velocity: float = 0.0) -> ExtensionTrajectory:
        """Forward simulation from any state (Algorithm 1, forward phase).

        At the actual (off-grid) state the step takes the control that minimises stage cost plus
        the interpolated cost-to-go over the admissible controls: the grid's controls inside the
        state's exact admissible interval, that interval's ends and the interpolated policy. Pure
        policy interpolation (the paper's forward pass) can drift off the feasible set between grid
        nodes on a fast path (P-VI vertical); this cannot cross a limit and costs a few ms more.
        Raises InfeasibleStart when a state has no admissible control.
        """
        grid, ts = self.grid, float(self.samples.time[1] - self.samples.time[0])
        n = self.samples.stages
        c = np.empty(n + 1)
        v = np.empty(n + 1)
        a = np.zeros(n + 1)
        c[0], v[0] = float(start_position), float(start_velocity)
        table = cylinder_table(self.crane)
        hydraulics = _hydraulics(self.crane)
        mode = _MODES.get(self.cost, 0)
        for k in range(n):
            terms = stage_terms(self.crane, self.samples, k, np.array(c[k]), np.array(v[k]), self.cost)
            where = f"start c = {c[0]:.4f} m, v = {v[0]:.4f} m/s: stage {k} (t = {self.samples.time[k]:.2f} s)"
            if not terms.admissible:
                raise InfeasibleStart(f"{where}: state violates a position or velocity limit")
            low, high = _control_window(
                terms.acc_offset, terms.acc_slope, table[:, 5], v[k], grid.velocities[0], grid.velocities[-1],
                grid.controls, ts, self.acceleration_limits,
            )
            nodes = grid.positions[k + 1]
            x = (c[k] + ts * v[k] - nodes[0]) / (nodes[1] - nodes[0])
            if low > high + 1e-12 or not -1e-9 <= x <= len(nodes) - 1 + 1e-9:
                raise InfeasibleStart(f"{where}: no admissible acceleration")
            ic = min(max(int(np.floor(x)), 0), len(nodes) - 2)
            wc = _snap(x - ic)
            candidates = [u for u in grid.controls if low <= u <= high] + [low, high, min(max(-v[k] / ts, low), high)]
            guided = _interpolate_policy(self.policy[k], self.cost_to_go[k], grid.positions[k], grid.velocities, c[k], v[k])
            if not math.isnan(guided):
                candidates.append(min(max(guided, low), high))
            options = np.array(candidates)
            candidates = list(options[self._leads_on(k, c[k] + ts * v[k], v[k] + ts * options)])
            best, best_u = np.inf, None
            for u in candidates:
                y = (v[k] + ts * u - grid.velocities[0]) / (grid.velocities[1] - grid.velocities[0])
                stage = _stage_power_at(
                    mode, float(terms.base_cost), float(terms.flow), terms.force_offset, terms.force_slope, terms.velocity,
                    table, hydraulics, u,
                )
                total = ts * stage + _cost_to_go_at(self.cost_to_go[k + 1], ic, wc, y)
                if total < best:
                    best, best_u = total, u
            if best_u is None:
                raise InfeasibleStart(f"{where}: every admissible acceleration leads to an inadmissible state")
            a[k] = best_u
            c[k + 1] = c[k] + ts * v[k]
            v[k + 1] = v[k] + ts * a[k]
        return ExtensionTrajectory(c, v, a, ts)


    def follow(self, start_position: float, start_velocity: float = 0.0) -> ExtensionTrajectory:
        """The fast forward pass for re-planning on line: P-VI's interpolated policy (compiled, well under a
        millisecond), checked in one vectorised pass against every position, velocity and acceleration
        limit at the exact states. Where it would leave the admissible set (a fast path riding a limit,
        P-VI vertical) or runs out of feasible nodes, ``forward``'s search takes over."""
        ts = float(self.samples.time[1] - self.samples.time[0])
        c, v, a, reached = _follow_policy(
            self.policy, self.cost_to_go, self.grid.positions, self.grid.velocities, self.grid.controls,
            float(start_position), float(start_velocity), ts,
        )
        if reached == self.samples.stages:
            trajectory = ExtensionTrajectory(c, v, a, ts)
            with np.errstate(invalid="ignore"):
                checks = self.crane.limit_checks(crane_motion(self.crane, self.samples, trajectory, forces=False))
            applied = checks["acceleration"][:-1].all() or not self.acceleration_limits  # a_N is never applied
            if checks["position"].all() and checks["velocity"].all() and applied:
                return trajectory
        return self.forward(start_position, start_velocity)

    def _leads_on(self, k: int, c_next: float, v_next: np.ndarray) -> np.ndarray:
        """Which next states are admissible at stage k+1 and move on to an admissible position at k+2
        (c'' = c' + T_s v' does not depend on the control chosen at k+1: a dead end shows here first)."""
        ts = float(self.samples.time[1] - self.samples.time[0])
        ok = stage_terms(self.crane, self.samples, k + 1, np.full_like(v_next, c_next), v_next, Cost.CP).admissible
        if k + 2 <= self.samples.stages:
            ok &= stage_terms(self.crane, self.samples, k + 2, c_next + ts * v_next, v_next, Cost.CP).admissible
        return ok


def _pressure_lines(table: np.ndarray, hydraulics: np.ndarray) -> np.ndarray:
    """(n_cyl, 2, 2): per cylinder, extending and retracting, the intercept and gain of ``driven_pressure``
    = intercept + gain F, which holds wherever the cylinder drives (F v > 0 beyond the drive threshold);
    0 and 0 for a side that never drives (a single-acting cylinder lowering to tank)."""
    lines = np.zeros((len(table), 2, 2))
    speed = 2.0 * hydraulics[2] + 1e-3
    for side, sign in enumerate((1.0, -1.0)):
        at_one, at_two = (
            driven_pressure(force * sign, speed * sign, table[:, 0], table[:, 1], table[:, 2], *hydraulics[:3]) for force in (1.0, 2.0)
        )
        gain = sign * (at_two - at_one)
        lines[:, side] = np.stack([at_one - gain * sign, gain], axis=1)
    return lines


def _hydraulics(crane: Crane) -> np.ndarray:
    h = crane.hydraulics
    return np.array([h["compensator_drop"], h["tank_pressure"], h["drive_threshold"], h["ls_margin"], h["efficiency"]])


@njit(cache=True)
def _interpolate_policy(
    policy: np.ndarray, cost: np.ndarray, positions: np.ndarray, velocities: np.ndarray, c: float, v: float
) -> float:
    """Bilinear interpolation of one stage's policy at (c, v) over its feasible nodes; NaN where none is."""
    x = np.interp(c, positions, np.arange(positions.shape[0]).astype(np.float64))
    y = np.interp(v, velocities, np.arange(velocities.shape[0]).astype(np.float64))
    i = min(int(x), positions.shape[0] - 2)
    j = min(int(y), velocities.shape[0] - 2)
    wc, wv = x - i, y - j
    total = 0.0
    weight_sum = 0.0
    for di in range(2):
        for dj in range(2):
            weight = (wc if di else 1.0 - wc) * (wv if dj else 1.0 - wv)
            if weight > 0.0 and cost[i + di, j + dj] < _FEASIBLE_BELOW:
                total += weight * policy[i + di, j + dj]
                weight_sum += weight
    return total / weight_sum if weight_sum > 0.0 else np.nan


@njit(cache=True)
def _follow_policy(
    policy: np.ndarray, cost_to_go: np.ndarray, positions: np.ndarray, velocities: np.ndarray, controls: np.ndarray,
    c0: float, v0: float, ts: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """P-VI's forward phase: the policy interpolated at each state, kept within the control and velocity
    grids; returns c, v, a and the stage reached (< N where no feasible node surrounds the state)."""
    n = policy.shape[0]
    c = np.zeros(n + 1)
    v = np.zeros(n + 1)
    a = np.zeros(n + 1)
    c[0] = c0
    v[0] = v0
    for k in range(n):
        u = _interpolate_policy(policy[k], cost_to_go[k], positions[k], velocities, c[k], v[k])
        if np.isnan(u):
            return c, v, a, k
        u = min(max(u, controls[0], (velocities[0] - v[k]) / ts), controls[-1], (velocities[-1] - v[k]) / ts)
        a[k] = u
        c[k + 1] = c[k] + ts * v[k]
        v[k + 1] = v[k] + ts * u
    return c, v, a, n


def solve(
    crane: Crane,
    samples: PathSamples,
    cost: Cost,
    grid: DpGrid,
    *,
    acceleration_limits: bool = True,
    progress: bool = False,
) -> DpSolution:
    """Backward phase of Algorithm 1 on the grid; returns the tables."""
    if len(grid.positions) != samples.stages + 1:
        raise ValueError(f"DP grid for {len(grid.positions) - 1} stages, path of {samples.stages}: build it with DpGrid.for_path")
    v = grid.velocities[None, :]
    n = samples.stages
    ts = float(samples.time[1] - samples.time[0])
    n_c, n_v, _ = grid.shape
    cost_to_go = np.empty((n + 1, n_c, n_v))
    policy = np.empty((n, n_c, n_v), dtype=np.float32)
    cost_to_go[n] = terminal_cost(crane, samples, grid)
    table = cylinder_table(crane)
    hydraulics = _hydraulics(crane)
    pressure_lines = _pressure_lines(table, hydraulics)
    mode = _MODES.get(cost, 0)
    # rows differ in their admissible states (up to 58:42 between halves), so the threads take them in small chunks
    with parallel_chunksize(8):
        for k in tqdm(range(n - 1, -1, -1), desc=f"DP {cost.value} backward", unit="stage", disable=not progress):
            terms = stage_terms(crane, samples, k, grid.positions[k][:, None], v, cost)
            cost_to_go[k], policy[k] = _bellman_step(
                cost_to_go[k + 1], grid.positions[k], grid.positions[k + 1], grid.velocities, grid.controls, ts, mode,
                terms.admissible, terms.base_cost, terms.flow, terms.acc_offset, terms.acc_slope, table[:, 5],
                terms.force_offset, terms.force_slope, terms.velocity, table, hydraulics, pressure_lines, acceleration_limits,
            )
    return DpSolution(crane, samples, grid, cost, acceleration_limits, cost_to_go, policy)


def start_position(crane: Crane, samples: PathSamples, grid: DpGrid, which: str = "smallest") -> float:
    """Initial extension of P-V / P-VI: the smallest feasible grid position at the path start at rest,
    or the grid position midway between the smallest and largest (P-VI's second configuration)."""
    nodes = grid.positions[0]
    terms = stage_terms(crane, samples, 0, nodes, np.zeros_like(nodes), Cost.CP)
    feasible = nodes[terms.admissible]
    if feasible.size == 0:
        raise InfeasibleStart(f"path start {samples.position[0].tolist()}: no extension reaches it within the joint limits")
    if which == "smallest":
        return float(feasible[0])
    if which == "middle":
        middle = 0.5 * (feasible[0] + feasible[-1])
        return float(nodes[np.argmin(np.abs(nodes - middle))])
    raise InputError(f"start {which!r} (smallest or middle)")
