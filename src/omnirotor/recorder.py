"""A preallocated, labelled log of a loop: one row per step, named column groups.

A :class:`Recorder` owns a ``(capacity, n_signals)`` float array. The loop writes row ``n`` and moves on;
reports read whole columns afterwards. Nothing is allocated per row.

Two ways to write a row:

* :meth:`Recorder.record` takes one value per group (a float, or an array of the group's width);
* for the hot loop, :meth:`Recorder.bind` fixes once the persistent arrays whose concatenation is a row
  (the producers' own output buffers; one array may hold several consecutive groups), and
  :meth:`Recorder.record_bound` then copies them all into the next row with a single
  ``np.concatenate(..., out=row)``;
* a producer that computes the row itself (e.g. in a compiled kernel) takes :meth:`Recorder.next_row` and
  fills it in place; a recorder made with a ``record_dtype`` (a structured dtype of float64 fields, one row
  each) also gives the next row as a ``(1,)`` record of that dtype (:meth:`Recorder.next_record`), the same
  memory as the float row, so a kernel that writes records by field name writes the log without a copy.

A full recorder drops further rows (it never raises inside a loop) and counts them in
:attr:`Recorder.dropped`; :meth:`Recorder.ensure_capacity` grows it beforehand. A recorder made with
``grow_rows`` > 0 never drops: when full it starts a new chunk of that many rows (the rows written stay where
they are: no copy inside the loop, only a zeroed allocation once per chunk), and :attr:`Recorder.data` joins the
chunks once when it is read. A controller logging an open-ended flight (a flight node) has no cap so.

Column names: a group of width 1 has one column named like the group; a wider group ``g`` has columns
``g.<label>`` with the labels given, or ``g.0``, ``g.1``, ... by default.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from omnirotor.errors import InputError

__all__ = ["Recorder", "GroupSpec"]

GroupSpec = tuple[str, int | Sequence[str]]
"""A column group: ``(name, width)`` or ``(name, labels)``."""


class Recorder:
    """A ``(capacity, n_signals)`` float log with named column groups.

    Args:
        capacity: number of rows (steps) preallocated.
        groups: the column groups in row order, each ``(name, width)`` or ``(name, labels)``.
        grow_rows: rows of each further chunk once full (module docstring); 0: a full recorder drops rows.
        record_dtype: the row as a record (module docstring): float64 fields only, as many floats as a row has.

    Attributes:
        data: (capacity, n_signals) the storage; rows ``[0, n)`` are valid (the chunks joined, module docstring).
        n: number of rows written.
        dropped: rows refused because the recorder was full.
        group_names: the group names in order.
        column_names: every column name in order.
    """

    def __init__(
        self, capacity: int, groups: Sequence[GroupSpec], *, grow_rows: int = 0, record_dtype: np.dtype | None = None
    ) -> None:
        if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 0:
            raise InputError(f"recorder capacity must be an integer >= 0, got {capacity!r}")
        if isinstance(grow_rows, bool) or not isinstance(grow_rows, int) or grow_rows < 0:
            raise InputError(f"recorder grow_rows must be an integer >= 0, got {grow_rows!r}")
        self.grow_rows = grow_rows
        self._chunks: list[np.ndarray] = []  # full chunks before the current one (``_data``)
        self._base = 0  # rows in them
        self._slices: dict[str, slice] = {}
        self.column_names: list[str] = []
        start = 0
        for name, spec in groups:
            if name in self._slices:
                raise InputError(f"recorder: duplicate group {name!r}")
            if isinstance(spec, int):
                if spec < 1:
                    raise InputError(f"recorder group {name!r}: width must be >= 1, got {spec}")
                labels = [str(i) for i in range(spec)]
            else:
                labels = [str(s) for s in spec]
                if not labels:
                    raise InputError(f"recorder group {name!r}: no labels")
            width = len(labels)
            self._slices[name] = slice(start, start + width)
            self.column_names.extend([name] if width == 1 else [f"{name}.{lab}" for lab in labels])
            start += width
        if len(set(self.column_names)) != len(self.column_names):
            raise InputError("recorder: duplicate column names")
        self._columns = {c: i for i, c in enumerate(self.column_names)}
        self.group_names = list(self._slices)
        self._slice_list = list(self._slices.values())
        self.n_signals = start
        if record_dtype is not None and (
            record_dtype.itemsize != 8 * start
            or any(np.dtype(f[0]).base != np.float64 for f in record_dtype.fields.values())
        ):
            raise InputError(f"recorder: record_dtype is not {start} float64 values")
        self.record_dtype = record_dtype
        self._records: np.ndarray | None = None  # the current chunk as records (with a record_dtype)
        self._data = self._storage(np.zeros((capacity, start)))
        self.n = 0
        self.dropped = 0
        self._bound: tuple[np.ndarray, ...] | None = None

    @property
    def data(self) -> np.ndarray:
        """(capacity, n_signals) the storage; rows ``[0, n)`` are valid. Joins the chunks (once) if it grew."""
        if self._chunks:
            self._data = self._storage(np.concatenate([*self._chunks, self._data]))
            self._chunks = []
            self._base = 0
        return self._data

    @data.setter
    def data(self, value: np.ndarray) -> None:
        self._chunks = []
        self._base = 0
        self._data = self._storage(value)

    def _storage(self, data: np.ndarray) -> np.ndarray:
        """``data`` as the current chunk (its records kept beside it when the recorder has a record dtype)."""
        if self.record_dtype is not None:
            self._records = data.view(self.record_dtype).reshape(-1)  # the same dtype object: typed fast by numba
        return data

    @property
    def capacity(self) -> int:
        """Number of rows allocated."""
        return self._base + self._data.shape[0]

    def clear(self) -> None:
        """Forget every row (the storage is kept)."""
        self.data  # noqa: B018 (joins the chunks: their storage is kept as one)
        self.n = 0
        self.dropped = 0

    def ensure_capacity(self, rows: int) -> None:
        """Grow the storage to at least ``rows`` rows, keeping the rows written (call outside loops)."""
        if rows > self.capacity:
            data = self.data
            new = np.zeros((rows, self.n_signals))
            new[: self.n] = data[: self.n]
            self.data = new

    def _free_row(self) -> np.ndarray | None:
        """The storage row of row ``n`` (a new chunk started when full and growing), or None when full."""
        i = self.n - self._base
        if i < self._data.shape[0]:
            return self._data[i]
        if self.grow_rows == 0:
            return None
        if self._data.shape[0]:
            self._chunks.append(self._data)
            self._base += self._data.shape[0]
        self._data = self._storage(np.zeros((self.grow_rows, self.n_signals)))
        return self._data[self.n - self._base]

    def record(self, *values: float | np.ndarray) -> bool:
        """Write the next row: one value per group, in group order.

        Returns:
            False if the recorder was full and the row was dropped.
        """
        if len(values) != len(self._slice_list):
            raise InputError(f"recorder.record: expected {len(self._slice_list)} values, got {len(values)}")
        row = self._free_row()
        if row is None:
            self.dropped += 1
            return False
        for sl, v in zip(self._slice_list, values, strict=True):
            row[sl] = v
        self.n += 1
        return True

    def bind(self, *sources: np.ndarray) -> None:
        """Fix the arrays that :meth:`record_bound` copies: 1-D float arrays whose concatenation is a row.

        An array may span several consecutive groups; the widths must add up to :attr:`n_signals`. The
        arrays must stay the same objects (their contents change from row to row).
        """
        for src in sources:
            if not isinstance(src, np.ndarray) or src.ndim != 1 or src.dtype != np.float64:
                raise InputError("recorder.bind: every source must be a 1-D float64 array")
        width = sum(src.shape[0] for src in sources)
        if width != self.n_signals:
            raise InputError(f"recorder.bind: sources have {width} values in all, a row has {self.n_signals}")
        self._bound = tuple(sources)

    def record_bound(self) -> bool:
        """Write the next row from the bound arrays (see :meth:`bind`); False if full."""
        row = self._free_row()
        if row is None:
            self.dropped += 1
            return False
        np.concatenate(self._bound, out=row)
        self.n += 1
        return True

    def next_row(self) -> np.ndarray | None:
        """The next row, counted as written, for a producer that fills it in place.

        Returns:
            A view of the row, or None (counted as dropped) when the recorder is full (and does not grow).
        """
        n = self.n
        data = self._data
        i = n - self._base
        if i < data.shape[0]:  # the common case, inline (one call per control period)
            self.n = n + 1
            return data[i]
        row = self._free_row()
        if row is None:
            self.dropped += 1
            return None
        self.n = n + 1
        return row

    def next_record(self) -> np.ndarray | None:
        """:meth:`next_row` as a ``(1,)`` record of :attr:`record_dtype` (the same memory; module docstring)."""
        n = self.n
        i = n - self._base
        if i < self._data.shape[0]:  # the common case, inline (one call per control period)
            self.n = n + 1
            return self._records[i : i + 1]
        if self._free_row() is None:
            self.dropped += 1
            return None
        self.n = n + 1
        i = n - self._base
        return self._records[i : i + 1]

    def column(self, name: str) -> np.ndarray:
        """(n,) view of one column (a column name, or the name of a width-1 group)."""
        try:
            j = self._columns[name]
        except KeyError:
            raise InputError(f"recorder: no column {name!r}") from None
        return self.data[: self.n, j]

    def group(self, name: str) -> np.ndarray:
        """(n, width) view of a group's columns; (n,) for a width-1 group."""
        try:
            sl = self._slices[name]
        except KeyError:
            raise InputError(f"recorder: no group {name!r}; groups: {', '.join(self.group_names)}") from None
        view = self.data[: self.n, sl]
        return view[:, 0] if sl.stop - sl.start == 1 else view

    def width(self, name: str) -> int:
        """Number of columns of a group."""
        sl = self._slices[name]
        return sl.stop - sl.start

    def to_npz(self, path: str | Path) -> None:
        """Save the valid rows: one array per group, plus ``_columns`` (all column names) and ``_groups``."""
        arrays = {name: np.array(self.group(name)) for name in self.group_names}
        arrays["_columns"] = np.array(self.column_names)
        arrays["_groups"] = np.array(self.group_names)
        arrays["_widths"] = np.array([self.width(g) for g in self.group_names])
        from omnirotor.safe_io import atomic_path

        with atomic_path(path) as tmp, open(tmp, "wb") as fh:  # a file object: numpy adds no ".npz"
            np.savez_compressed(fh, **arrays)

    @classmethod
    def from_npz(cls, path: str | Path) -> Recorder:
        """Load a recorder saved by :meth:`to_npz` (capacity = rows saved)."""
        from omnirotor.safe_io import check_input_file

        with np.load(check_input_file(path)) as z:  # a regular file: a FIFO is refused, not waited on
            groups = [str(g) for g in z["_groups"]]
            columns = [str(c) for c in z["_columns"]]
            widths = [int(w) for w in z["_widths"]]
            specs: list[GroupSpec] = []
            i = 0
            for g, w in zip(groups, widths, strict=True):
                cols = columns[i : i + w]
                specs.append((g, 1) if w == 1 else (g, [c[len(g) + 1 :] for c in cols]))
                i += w
            first = np.asarray(z[groups[0]])
            rec = cls(int(first.shape[0]), specs)
            for g in groups:
                rec.data[:, rec._slices[g]] = np.asarray(z[g]).reshape(rec.capacity, -1)
            rec.n = rec.capacity
        return rec
