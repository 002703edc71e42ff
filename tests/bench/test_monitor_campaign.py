"""bench --fuzz --only monitor: the monitoring engine's campaigns, bounded (the long run is in docs/benchmarks.md)."""

from bench.monitor_campaign import failed, report


def test_the_campaign_tables_count_no_traceback_missed_bump_or_false_alarm():
    text = report(examples=2, composed=2, replays=1, seed=1)
    assert "no invariant broken" in text
    for reference in ("session", "result.yaml", "previous run"):
        assert f"Armed from {reference}:" in text
    assert text.count("| all |") == 4 and not failed(text)
    # The check reads the tables: a row of the total with a missed bump is a failure.
    assert failed("| all |  | 1 | 0 | 1 | 1 | 0 | 0 | 1 | 0 | 0 |")
    assert not failed("| all |  | 1 | 0 | 1 | 1 | 1 | 0 | 0 | 0 | 0 |")
