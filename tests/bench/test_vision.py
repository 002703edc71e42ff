"""bench.vision runs end to end (tiny sample) and writes its table and plot."""

from bench import vision


def test_bench_vision_smoke(tmp_path, capsys):
    assert vision.main(["--frames", "2", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "| extract = detect + PnP + depth plane + center |" in out
    assert "| 0.5-0.6 |" in out and "NEES mean" in out
    assert (tmp_path / "vision_accuracy.png").stat().st_size > 10_000
