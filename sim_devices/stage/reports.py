"""When GRBL 1.1h's status report carries ``WCO`` and ``Ov`` (``report_realtime_status``).

After a reset both counters are 0: the first report has ``WCO`` (and sets the override
counter to 1, so ``Ov`` comes in the second). Then ``WCO`` every
``REPORT_WCO_REFRESH_IDLE_COUNT`` = 10 reports (``..._BUSY_COUNT`` = 30 while running,
holding, jogging or homing) and ``Ov`` every 10 (20 busy); a work-offset change (``G10``,
``G92``, ``G54``...) brings ``WCO`` into the next report (``system_flag_wco_change``).

>>> r = ReportRefresh()
>>> [r.next(busy=False) for _ in range(3)]
[(True, False), (False, True), (False, False)]
"""

from __future__ import annotations

from dataclasses import dataclass

WCO_REFRESH = {False: 10, True: 30}  # REPORT_WCO_REFRESH_{IDLE,BUSY}_COUNT
OVR_REFRESH = {False: 10, True: 20}  # REPORT_OVR_REFRESH_{IDLE,BUSY}_COUNT


@dataclass
class ReportRefresh:
    """The two refresh counters of ``sys`` (``report_wco_counter``, ``report_ovr_counter``)."""

    wco: int = 0
    ovr: int = 0

    def offset_changed(self) -> None:
        """A work offset changed: ``WCO`` in the next report."""
        self.wco = 0

    def next(self, *, busy: bool) -> tuple[bool, bool]:
        """Whether the report being composed carries ``(WCO, Ov)``."""
        show_wco = self.wco == 0
        if show_wco:
            self.wco = WCO_REFRESH[busy] - 1
            if self.ovr == 0:
                self.ovr = 1
        else:
            self.wco -= 1
        show_ov = self.ovr == 0
        if show_ov:
            self.ovr = OVR_REFRESH[busy] - 1
        else:
            self.ovr -= 1
        return show_wco, show_ov
