"""What the orientation says: an intermediate (growth-round) adjustment that stops at its iteration cap is no failure of
the run, and must not print "adjustment failed" in a run that succeeds (seen on strecha-entry-p10, exit 0); the
same warning outside a growth round still reaches the user."""

from __future__ import annotations

import logging

from skyrig.orient.gnss_block import intermediate_adjustment


def test_growth_round_failure_is_demoted_and_a_final_failure_is_not(caplog):
    lg = logging.getLogger("skyrig.adjust.adjust")
    with caplog.at_level(logging.WARNING):
        with intermediate_adjustment():
            lg.warning("adjustment failed: %s", "the adjustment did not converge")
        assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
        lg.warning("adjustment failed: %s", "the adjustment did not converge")
    assert [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING] == [
        "adjustment failed: the adjustment did not converge"]
    caplog.clear()
    with caplog.at_level(logging.INFO):
        with intermediate_adjustment():
            lg.warning("adjustment failed: %s", "x")
            lg.warning("sigma0 %s", "is large")  # any other warning stays a warning
    levels = {r.getMessage(): r.levelname for r in caplog.records}
    assert levels == {"intermediate adjustment failed: x (the final adjustment decides)": "INFO",
                      "sigma0 is large": "WARNING"}
