"""The figures the README and docs quote come from files the benches write (benchmarks/figures.py):
the pages agree with docs/figures/, and the tools that keep them so do their job."""
import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
import bench_readme  # noqa: E402
import figures  # noqa: E402
import time_suite  # noqa: E402


def test_every_quoted_figure_is_the_one_its_file_holds():
    assert figures.stale() == [], "python benchmarks/figures.py render"


def test_the_readme_quotes_its_figures_from_files():
    readme = (ROOT / "README.md").read_text()
    quoted = set(figures.MARK.findall(readme))
    names = {name for name, _ in quoted}
    assert {"suite_time_empty_cache", "readme_garment_simulate"} <= names
    assert figures.TABLE.search(readme), "the README's table of headline figures"
    held = figures.load()
    for name in names:
        assert held[name]["command"].startswith("python benchmarks/")
        assert (ROOT / held[name]["command"].split()[1]).is_file()


def test_a_figure_recorded_anew_makes_the_pages_stale_until_rendered(tmp_path):
    folder = tmp_path / "figures"
    figures.record("suite_time", "9 min 37 s", 577.0, "s", what="the suite", command="python benchmarks/time_suite.py",
                   headline=True, folder=folder, load=0.5)
    figures.record("other", "3 s", 3.0, "s", what="not in the table", command="python x.py", folder=folder)
    held = figures.load(folder)
    assert held["suite_time"]["value"] == 577.0 and held["suite_time"]["load"] == 0.5
    page = ("Took <!-- figure: suite_time -->10 min<!-- /figure -->.\n"
            "<!-- figures: table -->\nold rows\n<!-- /figures -->\n")
    rendered = figures.render(page, held)
    assert "<!-- figure: suite_time -->9 min 37 s<!-- /figure -->" in rendered
    assert "old rows" not in rendered and "| the suite | **9 min 37 s** |" in rendered
    assert "not in the table" not in rendered  # headline=False
    assert figures.render(rendered, held) == rendered
    with pytest.raises(ValueError, match="'missing'"):
        figures.render("<!-- figure: missing -->1 s<!-- /figure -->", held)


def test_a_figure_file_is_checked_and_written_whole(tmp_path):
    with pytest.raises(ValueError, match="figure name"):
        figures.record("Suite Time", "1 s", 1, "s", what="", command="", folder=tmp_path)
    with pytest.raises(ValueError, match="one line"):
        figures.record("x", "a\nb", 1, "s", what="", command="", folder=tmp_path)
    assert list(tmp_path.iterdir()) == []  # nothing half-written
    (tmp_path / "y.json").write_text(json.dumps({"name": "z"}))
    with pytest.raises(ValueError, match="y.json"):
        figures.load(tmp_path)


def test_the_suite_timer_reads_pytests_summary():
    assert time_suite.parse_summary("...\n1216 passed in 577.12s (0:09:37)\n") == (1216, 577.12)
    assert time_suite.parse_summary("= 1210 passed, 6 skipped, 3 warnings in 600.5s (0:10:00) =") == (1210, 600.5)
    with pytest.raises(ValueError):
        time_suite.parse_summary("3 failed, 1213 passed in 600.0s")  # no figure from a failed suite
    assert time_suite.minutes(577.12) == "9 min 37 s"


def test_the_readme_bench_runs_the_readmes_own_recipe():
    lines = bench_readme.recipe_lines(ROOT / "README.md")
    assert lines[0].startswith(".venv/bin/python examples/garments/make_skirt.py")
    assert any(" simulate mesh " in f" {line} " for line in lines)
    argv = bench_readme.argv_of(lines[0])
    assert argv[0] == sys.executable and Path(argv[1]).is_file()
    assert bench_readme.argv_of("taichi-sim check skirt.npz")[1:] == ["-m", "taichi_sim", "check", "skirt.npz"]
