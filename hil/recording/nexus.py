"""Units and NeXus-style attributes of a run recording, for generic HDF5 viewers.

h5web, silx and NeXus readers plot a group whose ``NX_class`` is ``NXdata``: its ``signal``
attribute names the dataset to plot and ``axes`` the dataset(s) along its dimensions; the
file's ``default`` attribute names the group to open first. Every numeric column also carries
``units`` (UDUNITS spelling). The attributes describe the layout of
:mod:`hil.recording.schema`; they change no data and the reader ignores them.

Layout (``NX_class``):

- ``/`` ``NXroot``, ``default = "entry"`` (the NXentry of :mod:`hil.recording.instrument`,
  whose ``default`` is ``estimates``);
- ``/estimates`` ``NXdata``: ``range_m`` against ``t_s`` (``speed_mps``, ``snr_db`` as
  auxiliary signals);
- ``/telemetry`` ``NXdata``: the stage ``position_m`` against ``host_time_s``;
- ``/recording`` ``NXdata``: a link to ``/samples`` (frames x channels, ADC units) against
  the frame index;
- the other tables ``NXcollection``.
"""

from __future__ import annotations

from typing import Any

import h5py
import numpy as np

UNITS: dict[str, dict[str, str]] = {
    "estimates": {"t_s": "s", "range_m": "m", "speed_mps": "m/s", "snr_db": "dB",
                  "t_tx_s": "s", "alpha": "1", "score": "1"},
    "telemetry": {"host_time_s": "s", "position_m": "m", "velocity_mps": "m/s"},
    "sync": {"host_time_s": "s"},
    "flushes": {"clock_s": "s"},
}  # fmt: skip
"""Units of the table columns (``table -> column -> units``); sample indices are counts."""

PLOTS: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "estimates": ("range_m", "t_s", ("speed_mps", "snr_db")),
    "telemetry": ("position_m", "host_time_s", ("velocity_mps",)),
}
"""``table -> (signal, axis, auxiliary signals)`` of the NXdata tables."""

RECORDING = "recording"


def sample_units(dtype: np.dtype[Any]) -> str:
    """Units of the raw samples: ADC counts for integers, full scale for floats."""
    return "counts" if np.issubdtype(dtype, np.integer) else "FS"


def annotate(f: h5py.File, samples: str, tables: tuple[str, ...]) -> None:
    """Write the units and NeXus-style attributes into a new recording ``f``.

    ``samples``: path of the sample dataset; ``tables``: the table groups. Call before SWMR
    mode starts (attributes and links cannot be added afterwards).
    """
    f.attrs["NX_class"] = "NXroot"
    f.attrs["default"] = "estimates"  # the entry, once written, takes over
    for table in tables:
        group = f[table]
        if table in PLOTS:
            signal, axis, auxiliary = PLOTS[table]
            group.attrs["NX_class"] = "NXdata"
            group.attrs["signal"] = signal
            group.attrs["axes"] = [axis]
            group.attrs[f"{axis}_indices"] = 0
            group.attrs["auxiliary_signals"] = list(auxiliary)
        else:
            group.attrs["NX_class"] = "NXcollection"
        for column, units in UNITS.get(table, {}).items():
            group[column].attrs["units"] = units
        for column in group:
            if column.endswith("sample_index") or column == "row":
                group[column].attrs["units"] = "1"
    data = f[samples]
    data.attrs["units"] = sample_units(data.dtype)
    data.attrs["long_name"] = f"ADC samples ({data.attrs['units']}), frames x channels"
    view = f.create_group(RECORDING)
    view.attrs["NX_class"] = "NXdata"
    view.attrs["signal"] = "samples"
    view.attrs["axes"] = [".", "."]
    view["samples"] = h5py.SoftLink(f"/{samples}")
