"""The straightforward vectorised NumPy DP: the yardstick of the fast solver (tests and ``make bench``).

Every stage evaluates the full crane motion, stage cost, limits and interpolated cost-to-go on the
whole state x control grid (N_c x N_v x N_u arrays) and minimises over the control axis: what a first
prototype does (138 s and 0.86 GB for the P-VI grid, measured during development, not in the thesis: P-VI
Section 6 says only that its Matlab run nearly maxed out 8 GB of RAM). It shares the crane, the costs and the
terminal condition with ``dp.solve`` and nothing of its structure.
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from hydro_ros.models.crane import Crane
from hydro_ros.planning.costs import Cost, stage_power
from hydro_ros.planning.dp import EDGE_SLACK, INFEASIBLE, SNAP, DpGrid, DpSolution, terminal_cost
from hydro_ros.planning.paths import PathSamples


def _interpolate(table: np.ndarray, positions: np.ndarray, grid: DpGrid, c: np.ndarray, v: np.ndarray) -> np.ndarray:
    x = (c - positions[0]) / (positions[1] - positions[0])
    y = (v - grid.velocities[0]) / (grid.velocities[1] - grid.velocities[0])
    i = np.clip(np.floor(x).astype(int), 0, len(positions) - 2)
    j = np.clip(np.floor(y).astype(int), 0, len(grid.velocities) - 2)
    wc, wv = x - i, y - j
    wc = np.where(wc < SNAP, 0.0, np.where(wc > 1.0 - SNAP, 1.0, wc))
    wv = np.where(wv < SNAP, 0.0, np.where(wv > 1.0 - SNAP, 1.0, wv))
    return (1 - wc) * ((1 - wv) * table[i, j] + wv * table[i, j + 1]) + wc * ((1 - wv) * table[i + 1, j] + wv * table[i + 1, j + 1])


def solve_reference(
    crane: Crane,
    samples: PathSamples,
    cost: Cost,
    grid: DpGrid,
    *,
    acceleration_limits: bool = True,
    progress: bool = False,
) -> DpSolution:
    n_c, n_v, n_u = grid.shape
    v = np.broadcast_to(grid.velocities[None, :, None], (n_c, n_v, n_u))
    u = np.broadcast_to(grid.controls[None, None, :], (n_c, n_v, n_u))
    n = samples.stages
    ts = float(samples.time[1] - samples.time[0])
    cost_to_go = np.empty((n + 1, n_c, n_v))
    policy = np.empty((n, n_c, n_v), dtype=np.float32)
    cost_to_go[n] = terminal_cost(crane, samples, grid)
    v_next = v + ts * u
    slack = EDGE_SLACK * ts * (grid.velocities[1] - grid.velocities[0])  # as dp._bellman_step
    for k in tqdm(range(n - 1, -1, -1), desc=f"reference DP {cost.value}", unit="stage", disable=not progress):
        nodes, next_nodes = grid.positions[k], grid.positions[k + 1]
        c = np.broadcast_to(nodes[:, None, None], v.shape)
        c_next = c + ts * v
        inside = (
            (c_next >= next_nodes[0] - slack)
            & (c_next <= next_nodes[-1] + slack)
            & (v_next >= grid.velocities[0] - 1e-9)
            & (v_next <= grid.velocities[-1] + 1e-9)
        )
        tip, tip_vel, tip_acc = samples.at(k)
        with np.errstate(invalid="ignore"):
            motion = crane.motion(tip, tip_vel, tip_acc, c, v, u, forces=cost.depends_on_control)
            checks = crane.limit_checks(motion)
            admissible = inside & checks["position"] & checks["velocity"]
            if acceleration_limits:
                admissible &= checks["acceleration"]
            on_window = np.clip(c_next, next_nodes[0], next_nodes[-1])  # within the slack: on the end, as dp._bellman_step
            total = ts * stage_power(cost, crane, motion) + _interpolate(cost_to_go[k + 1], next_nodes, grid, on_window, v_next)
        total = np.where(admissible, total, np.inf)
        best = np.argmin(total, axis=-1)
        lowest = np.take_along_axis(total, best[..., None], axis=-1)[..., 0]
        cost_to_go[k] = np.minimum(lowest, INFEASIBLE)
        policy[k] = np.where(lowest < INFEASIBLE, grid.controls[best], np.nan)
    return DpSolution(crane, samples, grid, cost, acceleration_limits, cost_to_go, policy)
