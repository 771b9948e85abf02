"""An echo followed to a boundary no detection brought is reported there only where that
boundary's fit collects about what the echo's latest fit did (:data:`~hil.estimation.gcas.
readout.FOLLOW_DROP_DB`)."""

from __future__ import annotations

import numpy as np
import pytest

from hil.estimation.gcas.readout import FOLLOW_DROP_DB


@pytest.mark.slow
def test_a_speed_sidelobes_fit_is_not_followed_beside_the_echo() -> None:
    # Fig 6.4's point M = 5 at -5 dB per-sample SNR (seed 2064, point 5, rep 18): the
    # detection at hop 41 is fitted on a speed sidelobe (19.415 against 18.793 m/s, E/N0
    # 28.0 dB against the echo's 28.5) and remembered as a second echo; followed, its hop 43
    # fitted 19.545 m/s at 13.9 dB with the true echo taken out and was reported 0.92 m short
    # (2 false estimates in this trial before the rule, 0 with it; the 47 boundaries the same;
    # range RMSE 0.137 -> 0.027 m, what is left the sidelobe fit at hop 41 itself, 0.18 m short).
    from hil.evaluation.trials_ch6 import ch6_receiver_trial

    assert FOLLOW_DROP_DB == 6.0
    params = {"receiver": "gcas", "m_hops": 5, "snr_db": -5.0}
    out = ch6_receiver_trial(params, np.random.SeedSequence(2064, spawn_key=(5, 18)))
    assert (out["n_detected"], out["n_false"]) == (47, 0)
    assert out["range_rmse_m"] == pytest.approx(0.0268, abs=0.001)


@pytest.mark.slow
def test_a_chain_followed_off_its_echo_in_open_water_is_ended_by_the_lobe_decisions() -> None:
    # sim-06/07's three-state point at -20 dB per-sample SNR (seed 2070, point 2, rep 16):
    # the first detection (hop 4) is fitted off the echo, and its next boundaries followed
    # from it collect 16-17 dB each. In open water the lobe decisions stand for a followed
    # fit and move it off that chain (refused), so a later detection finds the echo (hop 10):
    # range SSE 2.04 m² over the 29 boundaries. Kept on the chain's lobe (the rule for a
    # window holding still water, CoherentRefiner.in_still_water) the chain was followed to
    # hop 22 and the echo's own detections began at hop 23: 44.2 m².
    from hil.evaluation.trials_ch6 import ch6_receiver_trial

    params = {"receiver": "gcas", "m_hops": 10, "family": "three-state", "snr_db": -20.0}
    out = ch6_receiver_trial(params, np.random.SeedSequence(2070, spawn_key=(2, 16)))
    assert (out["n_detected"], out["n_false"]) == (29, 0)
    assert out["range_sse_m2"] == pytest.approx(2.04, abs=0.01)
