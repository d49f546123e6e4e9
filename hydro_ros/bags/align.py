"""One sample aligner for the live node and the bag reader: per-topic values by stamp -> rows of samples.

Every measured quantity is a column named ``(quantity, name)``: ``("joint_position", "boom_joint")``,
``("pressure_a", "boom")``, ``("supply_pressure", "")``. :class:`SampleAligner` collects values of
any column at any stamp (one at a time from a subscription, or whole arrays from a bag) and hands
out rows in stamp order, NaN where a column had no value. :class:`SampleLayout` is the column set
of a machine's actuators and turns rows into :class:`~hydro_ros.contract.samples.Samples`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from hydro_ros.bags.cdr import CdrError, decode_fluid_pressure, decode_joint_state, decode_sample_block
from hydro_ros.contract import topics
from hydro_ros.contract.samples import Samples

Column = tuple[str, str]
MOBILE_QUANTITIES = topics.MOBILE_VALVE_PRESSURES  # pilot_pressure_1, pilot_pressure_2, compensator_pressure
PER_JOINT = ("joint_position", "joint_velocity")
PER_ACTUATOR = ("pressure_a", "pressure_b", "valve_command")


class SampleLayout:
    """The columns of a machine's samples: per actuator its joint, chamber pressures and command, then the supply."""

    def __init__(self, actuators: Sequence[str], joints: Sequence[str], *, mobile: bool = False) -> None:
        self.actuators = list(actuators)
        self.joints = list(joints)
        self.mobile = mobile
        per_actuator = (*PER_JOINT, *PER_ACTUATOR, *(MOBILE_QUANTITIES if mobile else ()))
        self.fields = per_actuator
        self.columns: list[Column] = [
            (quantity, joint if quantity in PER_JOINT else actuator)
            for actuator, joint in zip(self.actuators, self.joints) for quantity in per_actuator
        ] + [("supply_pressure", "")]
        self._index = {column: k for k, column in enumerate(self.columns)}

    def index(self, quantity: str, name: str = "") -> int:
        return self._index[(quantity, name)]

    @staticmethod
    def source(column: Column) -> str:
        """Where a column comes from on the graph or in a bag, as a user reads it in an error."""
        quantity, name = column
        if quantity in PER_JOINT:
            return f"{topics.JOINT_STATES} name {name!r}"
        if quantity == "valve_command":
            return f"{topics.VALVE_COMMANDS} name {name!r}"
        if quantity == "supply_pressure":
            return topics.SUPPLY_PRESSURE
        if quantity == "ls_pressure":
            return topics.LS_PRESSURE
        return topics.actuator_pressure(name, quantity)

    @property
    def field_names(self) -> list[str]:
        """The columns as the fields of a sample block (topics.SAMPLE_BLOCK): ``<joint or actuator>/<quantity>``."""
        return [f"{name}/{quantity}" if name else quantity for quantity, name in self.columns]

    def rows(self, samples: Samples) -> np.ndarray:
        """Samples with (n, A) per-actuator arrays -> rows of this layout's columns (the inverse of :meth:`samples`)."""
        n = len(samples.times)
        per = np.stack([np.asarray(getattr(samples, quantity), dtype=float).reshape(n, len(self.actuators)) for quantity in self.fields],
                       axis=2)
        return np.column_stack([per.reshape(n, -1), np.asarray(samples.supply_pressure, dtype=float).reshape(n)])

    def samples(self, times: np.ndarray, rows: np.ndarray) -> Samples:
        """Rows of this layout's columns -> Samples with (n, A) per-actuator arrays."""
        n = len(times)
        per = rows[:, :-1].reshape(n, len(self.actuators), len(self.fields))
        arrays = {quantity: per[:, :, k] for k, quantity in enumerate(self.fields)}
        return Samples(times=times, supply_pressure=rows[:, -1], **arrays)


def place_at_keys(column: np.ndarray, keys: np.ndarray, stamps: np.ndarray, values: np.ndarray) -> None:
    """Writes into ``column`` (one value per sorted unique key stamp: a bag's /joint_states stamps) the ``values`` whose
    stamp is a key; a value at another stamp belongs to no sample, and of two at one stamp the later counts."""
    if len(keys) and len(stamps):
        where = np.searchsorted(keys, stamps)
        known = where < len(keys)
        known[known] = keys[where[known]] == stamps[known]
        column[where[known]] = values[known]


class SampleAligner:
    """Collects column values by stamp and releases complete rows in stamp order.

    A row is released when every column has a value, or, still incomplete, once a complete row
    ``sync_window_ns`` newer exists (counted in ``incomplete``: the monitor sees a gap). Values
    stamped at or before the last released row arrive too late and are dropped (``out_of_order``).
    ``take(final=True)`` releases everything.
    """

    def __init__(self, columns: int, *, sync_window_ns: int = 0, max_pending_ns: int = 5_000_000_000) -> None:
        self.width = columns
        self.sync_window_ns = sync_window_ns
        self.max_pending_ns = max_pending_ns
        self.out_of_order = 0
        self.incomplete = 0
        self.restart()

    def restart(self) -> None:
        """Forget everything pending: alignment starts again on whatever time base comes next."""
        self._columns: list[np.ndarray] = []
        self._stamps: list[np.ndarray] = []
        self._values: list[np.ndarray] = []
        # single values as subscriptions deliver them: plain lists, made arrays once per take()
        self._one_columns: list[int] = []
        self._one_stamps: list[int] = []
        self._one_values: list[float] = []
        self._pending_stamps = np.zeros(0, dtype=np.int64)
        self._pending_rows = np.zeros((0, self.width))
        self._pending_present = np.zeros((0, self.width), dtype=bool)
        self.last_released = -(1 << 63)

    def put(self, column: int, stamp: int, value: float) -> None:
        """One value, as a subscription delivers it (the live path: no NumPy per message)."""
        if stamp <= self.last_released:
            self.out_of_order += 1
            return
        self._one_columns.append(column)
        self._one_stamps.append(stamp)
        self._one_values.append(value)

    def add(self, column: int, stamps: np.ndarray, values: np.ndarray) -> None:
        """Many values of one column (a bag's whole topic)."""
        stamps = np.asarray(stamps, dtype=np.int64)
        values = np.asarray(values, dtype=float)
        late = stamps <= self.last_released
        if late.any():
            self.out_of_order += int(np.count_nonzero(late))
            stamps, values = stamps[~late], values[~late]
        self._columns.append(np.full(len(stamps), column, dtype=np.int64))
        self._stamps.append(stamps)
        self._values.append(values)

    @property
    def pending(self) -> set[int]:
        """Stamps held back, waiting for a missing column."""
        return {int(stamp) for part in (self._pending_stamps, *self._stamps, self._one_stamps) for stamp in part}

    def _gather(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pending rows and the values added since, merged into one stamp-sorted matrix, and which cells arrived.

        A cell that arrived holding NaN (a sensor sending NaN) counts as arrived: the row is not
        held back for it, and the monitor sees the NaN as the gap it is.
        """
        if self._one_stamps:
            self._columns.append(np.array(self._one_columns, dtype=np.int64))
            self._stamps.append(np.array(self._one_stamps, dtype=np.int64))
            self._values.append(np.array(self._one_values, dtype=float))
            self._one_columns, self._one_stamps, self._one_values = [], [], []
        if not self._stamps:
            return self._pending_stamps, self._pending_rows, self._pending_present
        columns, stamps, values = (np.concatenate(parts) for parts in (self._columns, self._stamps, self._values))
        self._columns, self._stamps, self._values = [], [], []
        all_stamps = np.union1d(self._pending_stamps, stamps)
        rows = np.full((len(all_stamps), self.width), np.nan)
        present = np.zeros(rows.shape, dtype=bool)
        earlier = np.searchsorted(all_stamps, self._pending_stamps)
        rows[earlier] = self._pending_rows
        present[earlier] = self._pending_present
        where = np.searchsorted(all_stamps, stamps)
        known = (where < len(all_stamps)) & (all_stamps[np.minimum(where, len(all_stamps) - 1)] == stamps)
        rows[where[known], columns[known]] = values[known]
        present[where[known], columns[known]] = True
        return all_stamps, rows, present

    def take(self, *, final: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Stamps (ns) and rows ready now; the rest stays pending."""
        stamps, rows, present = self._gather()
        if len(stamps) == 0:
            return stamps, rows
        complete = present.all(axis=1)
        if final:
            ready = len(stamps)
        else:
            newest = stamps[complete].max() if complete.any() else stamps[-1] - self.max_pending_ns
            waiting = (stamps <= newest) & ~complete & (newest - stamps <= self.sync_window_ns)
            ready = int(np.searchsorted(stamps, newest, side="right"))
            if waiting.any():
                ready = min(ready, int(np.argmax(waiting)))
        self.incomplete += int(np.count_nonzero(~complete[:ready]))
        self._pending_stamps, self._pending_rows, self._pending_present = stamps[ready:], rows[ready:], present[ready:]
        if ready:
            self.last_released = int(stamps[ready - 1])
        return stamps[:ready], rows[:ready]


class ContractAligner(SampleAligner):
    """The live monitor's front: raw CDR messages of the contract topics into the columns of a layout.

    It also keeps the input's time base: the newest /joint_states stamp. A message more than
    ``jump_ns`` away from it is held off (counted in ``off_base``); ``confirm`` /joint_states
    messages in a row on a new, self-consistent time base are a time jump (a clock step, a bag
    looping, a sim-time reset): everything pending is dropped, the jump is recorded in
    ``time_jumps`` [s] and alignment restarts on the new base. A single stray stamp (one sample
    an hour in the future) is held off and forgotten, so it cannot freeze the monitor.
    """

    def __init__(self, layout: SampleLayout, *, sync_window_ns: int, max_pending_ns: int = 5_000_000_000,
                 jump_ns: int = 1_000_000_000, confirm: int = 20) -> None:
        super().__init__(len(layout.columns), sync_window_ns=sync_window_ns, max_pending_ns=max_pending_ns)
        self.jump_ns = jump_ns
        self.confirm = confirm
        self.base: int | None = None
        self._candidate: list[int] = []
        self.time_jumps: list[float] = []
        self.off_base = 0
        self._joints = {joint: (layout.index("joint_position", joint), layout.index("joint_velocity", joint)) for joint in layout.joints}
        self._commands = {actuator: layout.index("valve_command", actuator) for actuator in layout.actuators}
        self._fields = layout.field_names
        self._block_columns: tuple[tuple[str, ...], list[int]] | None = None  # field names of the last block, where each column is

    def put_block(self, data: bytes) -> None:
        """A sample block (topics.SAMPLE_BLOCK): every column of many samples; fields the layout lacks are ignored, and
        a block that lacks one of the layout's columns is refused naming them (nothing of it is taken)."""
        names, stamps, rows = decode_sample_block(data)
        if self._block_columns is None or self._block_columns[0] != tuple(names):
            where = {name: k for k, name in enumerate(names)}
            missing = [field for field in self._fields if field not in where]
            if missing:
                raise CdrError(f"sample block lacks {', '.join(missing)}")
            self._block_columns = (tuple(names), [where[field] for field in self._fields])
        if len(stamps) == 0 or not self._follow(int(stamps[-1])):
            return
        for column, source in enumerate(self._block_columns[1]):
            self.add(column, stamps, rows[:, source])

    def _on_base(self, stamp: int) -> bool:
        if self.base is None or abs(stamp - self.base) <= self.jump_ns:
            return True
        self.off_base += 1
        return False

    def _follow(self, stamp: int) -> bool:
        """Track the time base with a /joint_states stamp; whether the message belongs to it."""
        if self.base is None or abs(stamp - self.base) <= self.jump_ns:
            self._candidate = []
            self.base = stamp if self.base is None else max(self.base, stamp)
            return True
        if self._candidate and abs(stamp - self._candidate[-1]) > self.jump_ns:
            self._candidate = []
        self._candidate.append(stamp)
        if len(self._candidate) < self.confirm:
            self.off_base += 1
            return False
        self.time_jumps.append((self._candidate[0] - self.base) * 1e-9)
        self.restart()
        self.base, self._candidate = stamp, []
        return True

    def put_joint_states(self, data: bytes) -> None:
        stamp, names, position, velocity = decode_joint_state(data)
        if not self._follow(stamp):
            return
        for k, name in enumerate(names):
            columns = self._joints.get(name)
            if columns is not None:
                self.put(columns[0], stamp, position[k] if k < len(position) else math.nan)
                self.put(columns[1], stamp, velocity[k] if k < len(velocity) else math.nan)

    def put_commands(self, data: bytes) -> None:
        stamp, names, position, _ = decode_joint_state(data)
        if not self._on_base(stamp):
            return
        for k, name in enumerate(names):
            column = self._commands.get(name)
            if column is not None:
                self.put(column, stamp, position[k] if k < len(position) else math.nan)

    def put_pressure(self, data: bytes, column: int) -> None:
        stamp, value, _ = decode_fluid_pressure(data)
        if self._on_base(stamp):
            self.put(column, stamp, value)
