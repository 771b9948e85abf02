"""A measured echo's ghost at short M and low SNR: what is left there with the echo taken out
is the noise's reading, judged at the echo's E/N0 (:data:`hil.estimation.refine.GHOST_NOISE_Z`)."""

from __future__ import annotations

import numpy as np
import pytest

from hil.evaluation.trials_ch6 import ch6_receiver_trial

#: sim-05's sweep seed (hil/data/sweeps/sim05_range_rmse_vs_m.toml); its point 3 is M = 10
#: at -20 dB per-sample SNR (one target closing at 5-25 m/s from 30-90 m, 0.8 s).
SWEEP_SEED = 2069


@pytest.mark.slow
def test_short_windows_at_minus_20_db_do_not_fit_the_targets_ghosts() -> None:
    # The false estimates were the target's ghosts one tone spacing's speed away (12.8 m/s
    # read at -14.1, 17.5 at -10.5, ...), whose reading with the target taken out is the
    # noise's at this E/N0. Measured: 4 false alarms in 30 trials (0.29/s) while a ghost had
    # to read at most GHOST_LEFT of its echo, 1 now; 1276 boundaries detected both ways.
    n_false = n_detected = 0
    for rep in range(30):
        params = {"receiver": "gcas", "m_hops": 10, "snr_db": -20.0}
        out = ch6_receiver_trial(params, np.random.SeedSequence(SWEEP_SEED, spawn_key=(3, rep)))
        n_false += int(out["n_false"])
        n_detected += int(out["n_detected"])
    assert n_false <= 1 and n_detected >= 1276
