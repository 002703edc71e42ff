"""bench.grids runs end to end (two cells) through ``python -m bench --grids`` and writes its table."""

from bench.__main__ import main


def test_bench_grids_table(tmp_path, capsys):
    assert main(["--grids", "--cells", "2", "--n", "40", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    text = (tmp_path / "grids.md").read_text()
    assert text.strip() == out.strip()
    rows = [line for line in text.splitlines() if line.startswith("| eye_")]
    assert len(rows) == 6 and all("| 2/2 |" in row for row in rows)     # every result names what is open
    assert "| eye_in_hand | grid |" in text and "(3) |" in text            # the held camera position: 3 dof
