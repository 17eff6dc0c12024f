"""``jaxrt gallery``: progress per warp (each is a compile of its own)."""

from __future__ import annotations

import pytest

from jaxrt.sampling import warp as W
from jaxrt.validation import gallery


def test_gallery_shows_progress_per_warp(tmp_path, monkeypatch, capsys):
    pytest.importorskip("matplotlib")
    specs = [s for s in W.REGISTRY if s.name in ("square_to_disk", "disk")][:1] or W.REGISTRY[:1]
    monkeypatch.setattr(W, "REGISTRY", specs)
    results = gallery.make_gallery(tmp_path / "g.png", num_samples=2000, resolution=(8, 4),
                                   num_points=100, progress=True)
    err = capsys.readouterr().err
    assert len(results) == 1 and (tmp_path / "g.png").stat().st_size > 0
    assert "gallery" in err and "1/1" in err and specs[0].name in err
