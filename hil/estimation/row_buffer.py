"""A bounded history of per-sample rows (``(n, ...)`` arrays) with absolute sample indices.

Appending is amortised O(1) per row: rows are written into a larger array and the last
``keep`` rows are moved to the front only when it fills. Rows before the first append read as
zeros (the signal before the stream started or after a reset).

>>> import numpy as np
>>> rb = RowBuffer(keep=3, row_shape=(2,), dtype=np.float64)
>>> rb.append(np.arange(10.0).reshape(5, 2), first_index=0)
>>> rb.rows(np.array([2, 4])).tolist()
[[4.0, 5.0], [8.0, 9.0]]
>>> rb.next_index
5
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import DTypeLike, NDArray

from hil.errors import ConfigError
from hil.resident_arrays import resident_zeros


class RowBuffer:
    """History of the last ``keep`` rows (at least) of a per-sample stream.

    Parameters
    ----------
    keep:
        Rows that must stay readable behind the newest one.
    row_shape:
        Shape of one row.
    dtype:
        Element type.
    """

    def __init__(self, keep: int, row_shape: tuple[int, ...], dtype: DTypeLike) -> None:
        if keep < 1:
            raise ConfigError("keep", keep, ">= 1 row")
        self.keep = int(keep)
        self.row_shape = tuple(row_shape)
        self.dtype = np.dtype(dtype)
        self._cap = max(4 * self.keep, 4096)
        self.reset(0)

    def reset(self, next_index: int) -> None:
        """Clear to zeros; the next appended row has absolute index ``next_index``."""
        # Mapped now, not page by page as the stream first fills it (hil.resident_arrays).
        self._arr = resident_zeros((self._cap, *self.row_shape), self.dtype)
        self._w = self.keep
        self._next = int(next_index)

    @property
    def next_index(self) -> int:
        """Absolute index of the next row to be appended."""
        return self._next

    @property
    def available(self) -> int:
        """Rows readable behind :attr:`next_index` (the newest ``available`` rows)."""
        return self._w

    @property
    def array(self) -> NDArray[Any]:
        """The backing array; use :meth:`position` to index it."""
        return self._arr

    def position(self, index: NDArray[np.int64] | int) -> NDArray[np.int64]:
        """Backing-array positions of absolute indices (must be within the kept history)."""
        return np.asarray(index, dtype=np.int64) - (self._next - self._w)

    def append(self, rows: NDArray[Any], first_index: int) -> None:
        """Append ``rows`` (shape ``(n, *row_shape)``) whose first has index ``first_index``."""
        if first_index != self._next:
            raise ConfigError("first_index", first_index, f"== next_index = {self._next}")
        n = rows.shape[0]
        if self._w + n > self._arr.shape[0]:
            need = self.keep + n
            if need > self._arr.shape[0]:
                self._cap = max(2 * need, self._cap)
                new = resident_zeros((self._cap, *self.row_shape), self.dtype)
            else:
                new = self._arr
            new[: self.keep] = self._arr[self._w - self.keep : self._w]
            self._arr = new
            self._w = self.keep
        self._arr[self._w : self._w + n] = rows
        self._w += n
        self._next += n

    def rows(self, index: NDArray[np.int64]) -> NDArray[Any]:
        """Rows at absolute indices ``index`` (any shape), copied."""
        result: NDArray[Any] = self._arr[self.position(index)]
        return result

    def span(self, first: int, stop: int) -> NDArray[Any]:
        """Rows ``first .. stop − 1`` as a view (must be within the kept history)."""
        a = int(self.position(first))
        return self._arr[a : a + (stop - first)]
