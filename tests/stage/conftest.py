"""Shared simulator settings for the stage tests.

``LAB`` is a single-axis lab machine as the driver and simulator tests were written for:
GRBL built to home X alone, switches on X, homing, soft and hard limits on, 80 steps/mm,
1200 mm/min, 100 mm/s², 500 mm travel, ``$10=3`` (MPos and Bf), powered up 250 mm from
home. ``INSTANT`` is the same with no line latency, for tests of the motion model that
compare positions with closed forms from the instant a line is sent.
"""

from __future__ import annotations

from dataclasses import replace

from sim_devices.stage import GrblSimConfig

LAB = GrblSimConfig(
    steps_per_mm=80.0,
    max_rate_mm_min=1200.0,
    acceleration_mm_s2=100.0,
    max_travel_mm=500.0,
    soft_limits=True,
    hard_limits=True,
    homing=True,
    homing_feed_mm_min=100.0,
    homing_seek_mm_min=1000.0,
    homing_debounce_ms=0,
    status_mask=3,
    homing_cycles=("X",),
    switch_axes="X",
    power_up_position_mm=-250.0,
)
INSTANT = replace(LAB, line_latency_s=0.0)
FREE = replace(INSTANT, homing=False, soft_limits=False, hard_limits=False,
               power_up_position_mm=0.0)  # fmt: skip
