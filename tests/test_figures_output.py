"""Figures that show what a claim is judged by (issue 25 item 5): violin colours and legend, the map-switch
legend only with a switch, the point contact's target force, the peg's depth and tilt against their goals,
distinguishable sign-pattern colours, readable legends."""

import numpy as np
import pytest

from omnirotor.experiments import figures
from omnirotor.experiments.metrics import RunLog


@pytest.fixture
def captured(monkeypatch):
    """The figures handed to save_figure (not written, kept open)."""
    figs = []
    monkeypatch.setattr(figures, "save_figure", lambda fig, path, **kw: figs.append(fig) or path)
    yield figs
    import matplotlib.pyplot as plt

    for f in figs:
        plt.close(f)


def _log(n=400, switch=False):
    t = np.arange(n) * 0.01
    eye = np.repeat(np.eye(3)[None], n, axis=0)
    z3 = np.zeros((n, 3))
    region = np.zeros(n, dtype=int)
    if switch:
        region[n // 2 :] = 1
    contact = np.zeros(n, dtype=bool)
    contact[100:300] = True
    return RunLog(t, z3, eye, z3, eye, z3, eye, z3, z3 + [0, 0, 2.5], z3, z3, contact, region, np.ones((n, 8)), 0 * t)


def test_map_switch_is_named_only_when_one_happened(captured):
    figures.plot_run(_log(), "steady", "x.png", region_names=("R1", "R2"))
    figures.plot_run(_log(switch=True), "switching", "y.png", region_names=("R1", "R2"))
    titles = [f._suptitle.get_text() for f in captured]
    assert "map switch" not in titles[0] and "map switch" in titles[1]


def test_point_contact_target_force_is_drawn(captured):
    figures.plot_run(_log(), "point-contact", "x.png", force_target_N=3.0)
    labels = [line.get_label() for line in captured[0].axes[3].get_lines()]
    target = [x for x in labels if x.startswith("target")]
    assert target == ["target K_E × penetration (3.0 N)"]
    line = next(x for x in captured[0].axes[3].get_lines() if x.get_label() == target[0])
    assert set(line.get_ydata()) == {3.0}


def test_peg_figure_has_depth_and_tilt_against_their_goals(captured):
    log = _log()
    depth = np.clip((log.t - 1.0) * 0.1, 0.0, 0.16)
    tilt = np.linspace(10.0, 8.0, log.t.size)
    figures.plot_run(log, "peg", "x.png", peg=figures.PegPanel(depth, tilt, 0.17, 0.165, (3.0, 7.0)))
    fig = captured[0]
    panel = fig.axes[4]
    assert panel.get_ylabel() == "insertion depth [cm]" and panel.get_xlabel() == "time [s]"
    lines = {x.get_label(): x for x in panel.get_lines()}
    np.testing.assert_allclose(lines["insertion depth"].get_ydata(), 100 * depth)
    assert set(lines["goal ≥ 16.5 cm"].get_ydata()) == {16.5}
    legend = [t.get_text() for t in panel.get_legend().get_texts()]
    assert "peg tilt to hole axis" in legend and "tilt goal 3–7° (inserted)" in legend


def test_violin_bars_take_their_violins_colour_and_the_legend_is_outside(captured):
    rng = np.random.default_rng(0)
    samples = {m: {r: rng.normal(size=(50, 3)) for r in ("R1", "R4")} for m in ("nominal", "global", "piecewise")}
    figures.plot_hover_violins(samples, "v.png")
    fig = captured[0]
    from matplotlib.collections import LineCollection, PolyCollection

    for ax in fig.axes:
        bodies = [c for c in ax.collections if isinstance(c, PolyCollection)]
        bars = [c for c in ax.collections if isinstance(c, LineCollection)]
        assert len(bodies) == 6 and len(bars) == 12  # 3 maps x 2 regions; medians, mins, maxes, bars per map
        body_colours = {tuple(np.round(c.get_facecolor()[0][:3], 3)) for c in bodies}
        bar_colours = {tuple(np.round(c.get_color()[0][:3], 3)) for c in bars}
        assert bar_colours == body_colours  # the bars use the violins' colours, no other
        assert ax.get_legend() is None
    assert len(fig.legends) == 1  # one figure legend, outside the panels
    fig.canvas.draw()
    box = fig.legends[0].get_window_extent()
    assert all(box.y0 >= ax.get_window_extent().y1 for ax in fig.axes)


def test_sign_pattern_colours_are_distinguishable():
    from omnirotor.regions_from_signs import distinct_colors

    c = distinct_colors(57)
    d = np.linalg.norm(c[:, None] - c[None], axis=2) + 9 * np.eye(57)
    assert d.min() > 0.2  # tab20 repeated colours (distance 0) beyond 20 patterns
    assert np.linalg.norm(c, axis=1).min() > 0.25 and np.linalg.norm(c - 1, axis=1).min() > 0.25  # not black/white


def test_points_per_region_legend_is_words_not_a_dict(monkeypatch):
    import matplotlib.figure

    from omnirotor.studies.points_per_region import plot_points_per_region

    seen = []
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", lambda self, *a, **k: seen.append(self))
    stats = {"mean": 0.5, "ci95": [0.4, 0.6], "p10": 0.3, "p90": 0.7}
    result = {
        "counts": [5, 10],
        "regions": 3,
        "reps": 2,
        "noise": {"low": {"speed_std_hz": 0.2, "attitude_std_deg": 0.1}},
        "results": {"low": {"5": stats, "10": stats}},
    }
    plot_points_per_region(result, "p.png")
    texts = [t.get_text() for t in seen[0].axes[0].get_legend().get_texts()]
    assert texts == ["low noise: speeds ±0.2 Hz, attitude ±0.1° (1σ)"]
