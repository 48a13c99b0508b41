"""The generated results and the report's range channels.

``dtmbnav results`` must print every table from its walks, keep it as data
that a rerun reproduces and render the Markdown file from the data; the
report must draw each range channel the fusion takes against the right
truth (a tower difference against the difference of the two towers' direct
paths, not against tower 0's range).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import matplotlib.figure
import matplotlib.pyplot as plt
import numpy as np
import pytest

from dtmbnav.chain.report import RANGE_CHANNELS, direct_path_ranges, plot_ranges, true_channel_m
from dtmbnav.evaluation import results
from dtmbnav.evaluation.evaluate import EvaluationRow
from dtmbnav.evaluation.results_data import ResultsData, Section, Walks
from dtmbnav.evaluation.results_status import file_hash
from dtmbnav.evaluation.seeds import BURNED_SEEDS, REPORTING_SEEDS


def _rows(scenario: str, level: str, pf_95: float, seeds: int = 2) -> list[EvaluationRow]:
    common = dict(scenario=scenario, seeds=seeds, p68_m=1.0, max_m=9.0, heading_error_median_deg=0.25,
                  first_seed=200, level=level)
    return [EvaluationRow(filter="pdr", p95_m=5.0, reduction_95=None, reduction_95_vs_fix=None, **common),
            EvaluationRow(filter="pdr@fix", p95_m=4.0, reduction_95=None, reduction_95_vs_fix=None, **common),
            EvaluationRow(filter="pf", p95_m=pf_95, reduction_95=1 - pf_95 / 5.0, reduction_95_vs_fix=1 - pf_95 / 4.0,
                          worst_vs_fix=0.10, paper_reduction_95=0.41, **common),
            EvaluationRow(filter="ukf", p95_m=3.0, reduction_95=0.4, reduction_95_vs_fix=0.25, worst_vs_fix=0.0,
                          **common)]


def _walks(scenario: str, pf: tuple[float, ...]) -> list[dict[str, object]]:
    return [{"scenario": scenario, "k": k, "seed": 1000 + k, "first_seed": 200, "heading_error_deg": -0.5,
             "p95_m": {"pdr": 5.0, "pdr@fix": 4.0, "pf": value, "ukf": 3.0}} for k, value in enumerate(pf)]


def test_the_fusion_table_counts_the_walks_a_filter_made_worse():
    table, headline = results.fusion_table(_rows("park-loop-cw", "obs", 2.5), _walks("park-loop-cw", (2.0, 4.3)))
    lines = table.markdown().splitlines()
    assert len(lines) == 3 and lines[1].count("|") == lines[0].count("|") == lines[2].count("|")
    assert "2.50 m (50.0 % / 37.5 %)" in lines[2] and "+10.0 %" in lines[2] and "| 41 % |" in lines[2]
    # The figures are numbers in the data, each with the unit and digits it prints with.
    assert table.keys == ("park-loop-cw",) and table.id == "fusion"
    pf = table.rows[0][table.column(results.PF_COLUMN)]
    assert [(f.value, f.decimals, f.unit) for f in pf.figures] == [(2.5, 2, "m"), (50.0, 1, "%"), (37.5, 1, "%")]
    # Walk 1's PF (4.3 m) is more than 5 % worse than its PDR@fix (4.0 m); walk 0's is better.
    assert headline == [{"scenario": "park-loop-cw", "level": "obs", "walks": 2, "pdr": 5.0, "pdr_at_fix": 4.0,
                         "pf": 2.5, "reduction": 0.5, "reduction_at_fix": 0.375, "worst": 0.10, "walks_worse": 1,
                         "paper": 0.41}]


def _section(name: str, pf_95: float, first_seed: int = REPORTING_SEEDS.start) -> Section:
    """A fusion section as :func:`dtmbnav.evaluation.results.write_results` keeps it (one walk of park-loop-cw)."""
    level = "iq" if name == "fusion-iq" else "obs"
    table, headline = results.fusion_table(_rows("park-loop-cw", level, pf_95), _walks("park-loop-cw", (2.0,)))
    return Section(name, name, f"dtmbnav results --sections {name} --first-seed {first_seed}", (table,),
                   Walks(first_seed, 2, level), tuple(headline), commit="abc", date="2026-01-01", machine="a machine",
                   wall_s=61.0)


def test_a_section_run_alone_keeps_the_others_and_fills_the_readme(tmp_path):
    both = ResultsData().with_sections([_section("fusion-obs", 2.5), _section("fusion-iq", 3.5)], results.SECTIONS)
    # The file's order is SECTIONS', whatever order they were run in; a rerun of one section replaces it alone.
    text = both.markdown()
    assert text.index("section: fusion-iq") < text.index("section: fusion-obs")
    again = both.with_sections([_section("fusion-obs", 2.0)], results.SECTIONS)
    text = again.markdown()
    assert text.count("section: fusion-obs") == 1 and "3.50 m" in text and "2.00 m" in text
    assert "2.50 m" not in text
    assert again.with_sections([], results.SECTIONS) == again
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{results.HEADLINE_BEGIN}\nold\n{results.HEADLINE_END}\noutro\n")
    results.update_readme(readme, again)
    text = readme.read_text()
    assert "old" not in text and text.startswith("intro\n") and text.endswith(f"{results.HEADLINE_END}\noutro\n")
    iq_line, obs_line = [line for line in text.splitlines() if line.startswith("| park-loop-cw")]
    assert "| iq |" in iq_line and "3.50 m" in iq_line and "| obs |" in obs_line and "2.00 m" in obs_line
    # A section printed on a burned range is named as left out of the README, its rows not shown.
    burned = again.with_sections([_section("fusion-iq", 3.5, first_seed=BURNED_SEEDS[-1].start)], results.SECTIONS)
    headline = results.headline_table(burned)
    assert [line for line in headline.splitlines() if line.startswith("| park-loop-cw")] == [obs_line]
    assert "Not here until printed again on the reporting range" in headline and "`fusion-iq`" in headline


def test_a_section_is_written_to_the_data_and_the_markdown_rendered_from_it(tmp_path, monkeypatch):
    path = tmp_path / "results.md"
    printed = _section("fusion-obs", 2.5)
    monkeypatch.setattr(results, "section_runners",
                        lambda config: {"fusion-obs": lambda: replace(printed, commit="", date="", machine="")})
    written = results.write_results(path, ["fusion-obs"], results.ResultsConfig(), date="2026-02-03")
    kept = ResultsData.load(tmp_path / "results.json")
    assert kept == written and path.read_text() == kept.markdown()
    section = kept["fusion-obs"]
    assert section.date == "2026-02-03" and section.commit == results.commit_id()
    # What it ran is recorded: this module among the project's files, each with the hash of its contents.
    assert section.fingerprint["dtmbnav/evaluation/results.py"] == file_hash(Path(results.__file__))
    assert all(path.split("/")[0] in ("dtmbnav_core", "receiver", "sim", "fusion", "dtmbnav")
               for path in section.fingerprint)
    # A Markdown file without its data is refused rather than overwritten (its sections would be lost).
    (tmp_path / "results.json").unlink()
    with pytest.raises(ValueError, match="data file"):
        results.write_results(path, ["fusion-obs"], results.ResultsConfig())


def test_a_readme_without_the_markers_is_refused(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text("no block here\n")
    with pytest.raises(ValueError, match="headline"):
        results.update_readme(readme, ResultsData())
    # Refused before any walk runs (an unknown section would fail after the check; here none runs at all).
    with pytest.raises(ValueError, match="headline"):
        results.write_results(tmp_path / "r.md", [], results.ResultsConfig(), readme=readme)
    assert not (tmp_path / "r.md").exists()


def test_an_unknown_section_is_refused_before_any_work(tmp_path):
    with pytest.raises(ValueError, match="unknown section"):
        results.write_results(tmp_path / "r.md", ["fusion-everything"], results.ResultsConfig())
    assert not (tmp_path / "r.md").exists()


def _two_tower_truth(t_s: np.ndarray) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Tower 0's direct path shortens at 1 m/s, tower 1's lengthens at 0.5 m/s; a wall reflection of tower 0
    that the difference must not use."""
    r0, r1, wall = 3000.0 - t_s, 5000.0 + 0.5 * t_s, 3050.0 + 2.0 * t_s
    n = len(t_s)
    paths = {"t_s": np.concatenate([t_s, t_s, t_s]), "tower_id": np.repeat([0, 1, 0], n).astype(np.int16),
             "kind": np.repeat([0, 0, 3], n).astype(np.int8), "range_m": np.concatenate([r0, r1, wall])}
    frames = {"t_s": t_s, "range_m": r0}
    return frames, paths


def test_each_range_channel_is_drawn_against_its_own_truth(tmp_path, monkeypatch):
    t = np.linspace(0.0, 10.0, 101)
    truth_frames, truth_paths = _two_tower_truth(t)
    direct = direct_path_ranges(truth_paths)
    np.testing.assert_allclose(true_channel_m(None, t, truth_frames, direct), 3000.0 - t)
    np.testing.assert_allclose(true_channel_m((0, None), t, truth_frames, direct), 3000.0 - t)
    np.testing.assert_allclose(true_channel_m((1, 0), t, truth_frames, direct), 2000.0 + 1.5 * t)
    assert true_channel_m((2, 0), t, truth_frames, direct) is None
    # Without /truth/paths (files written before it), tower 0 comes from /truth/frames and no difference is known.
    np.testing.assert_allclose(true_channel_m((0, None), t, truth_frames, {}), 3000.0 - t)
    assert true_channel_m((1, 0), t, truth_frames, {}) is None
    frames = {"t_s": t, "range_change_m": -t, "first_path_range_change_m": np.where(t > 1.0, -(t - 1.0), np.nan),
              "range_difference_change_1_m": 1.5 * t, "range_difference_change_2_m": np.full(len(t), np.nan)}
    figures = []
    savefig = matplotlib.figure.Figure.savefig
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig",
                        lambda fig, *args, **kwargs: (figures.append(fig), savefig(fig, *args, **kwargs))[1])
    plot_ranges(tmp_path / "range.png", frames, 2.0, truth_frames, truth_paths)
    assert plt.imread(tmp_path / "range.png").ndim == 3
    # One row per channel with data (tower 2's is all NaN), the channel left and its error right.
    (figure,) = figures
    rows = np.reshape(figure.axes, (-1, 2))
    assert [ax.get_title() for ax in rows[:, 0]] == [title for _, title, _ in RANGE_CHANNELS[:3]]
    first = t > 1.0
    # Each channel is drawn against its own truth's change since the channel's first measured frame (the first
    # path's is 1.1 s): tower 0's range (-t), then the difference of the towers' direct paths (1.5 t).
    for (ax, ax_err), measured, ok, change in zip(rows, (-t, -(t - 1.0), 1.5 * t),
                                                  (np.ones_like(first), first, np.ones_like(first)),
                                                  (-t, 1.1 - t, 1.5 * t)):
        receiver, truth = ax.lines
        np.testing.assert_allclose(receiver.get_xdata(), t[ok] + 2.0)
        np.testing.assert_allclose(receiver.get_ydata(), measured[ok])
        np.testing.assert_allclose(truth.get_xdata(), t + 2.0)
        np.testing.assert_allclose(truth.get_ydata(), change, atol=1e-9)
        (error,) = ax_err.lines
        np.testing.assert_allclose(error.get_ydata(), measured[ok] - change[ok], atol=1e-9)
    assert [c for c, _, _ in RANGE_CHANNELS] == ["range_change_m", "first_path_range_change_m",
                                                 "range_difference_change_1_m", "range_difference_change_2_m"]
