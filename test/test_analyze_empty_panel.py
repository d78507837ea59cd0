"""``analyze --plots``: a tracking-error panel with nothing to show says why instead of staying blank."""
from __future__ import annotations

import numpy as np

from piezo_ff_ros.core.analysis import plot_run
from piezo_ff_ros.core.recording.run import RunData


def _texts(monkeypatch, run, tmp_path):
    import matplotlib.figure

    seen: list[list[str]] = []
    orig = matplotlib.figure.Figure.savefig

    def savefig(fig, *args, **kwargs):
        seen.append([t.get_text() for ax in fig.axes for t in ax.texts])
        return orig(fig, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", savefig)
    assert plot_run(run, tmp_path)
    return seen


def test_error_panel_without_reference_says_why(monkeypatch, tmp_path):
    n = 200
    t = np.arange(n) / 20000.0
    run = RunData(t, np.zeros((n, 2)), np.zeros((n, 2)), ("x", "y"))
    texts = _texts(monkeypatch, run, tmp_path)
    assert len(texts) == 1 and sum("no reference recorded" in s for s in texts[0]) == 2   # one per axis
    with_ref = RunData(t, np.zeros((n, 2)), np.zeros((n, 2)), ("x", "y"), reference=np.ones((n, 2)) * 1e-6)
    assert not any("no reference" in s for s in _texts(monkeypatch, with_ref, tmp_path / "b")[0])
