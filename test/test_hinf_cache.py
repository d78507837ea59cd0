"""The on-disk cache of H∞ designs (core/synthesis/cache.py): a design loaded from it is the fresh synthesis to the
last bit; any change of the plant or a weight misses; a damaged entry is synthesised and written again; ``off``
writes nothing; the compensator cascade builds from it."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from piezo_ff_ros.core.compensators.cascade import CompensatorCascade
from piezo_ff_ros.core.synthesis import cache as hinf_cache
from piezo_ff_ros.core.synthesis.hinf import synthesize_hinf
from piezo_ff_ros.core.transfer import FactoredTF, TFMatrix


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A private cache directory and the syntheses made through it (counted)."""
    monkeypatch.setenv(hinf_cache.CACHE_ENV, str(tmp_path / "hinf"))
    made = []
    real = hinf_cache.synthesize_hinf

    def counted(G_L, cfg):
        made.append(cfg)
        return real(G_L, cfg)

    monkeypatch.setattr(hinf_cache, "synthesize_hinf", counted)
    return tmp_path / "hinf", made


def _same_design(a, b, timings=True):
    for name in ("controller", "controller_full"):
        for m in ("A", "B", "C", "D"):
            x, y = np.asarray(getattr(getattr(a, name), m)), np.asarray(getattr(getattr(b, name), m))
            assert x.shape == y.shape and x.tobytes() == y.tobytes(), (name, m)
    assert np.asarray(a.hankel_singular_values).tobytes() == np.asarray(b.hankel_singular_values).tobytes()
    for f in dataclasses.fields(a):
        if f.name not in ("controller", "controller_full", "hankel_singular_values") \
                and (timings or not f.name.endswith("_s")):
            va, vb = getattr(a, f.name), getattr(b, f.name)
            assert va == vb or (va != va and vb != vb), f.name   # NaN == NaN here


def test_a_cached_design_is_the_fresh_synthesis_to_the_last_bit(paper_config, cache):
    folder, made = cache
    cfg = paper_config
    fresh = synthesize_hinf(cfg.dynamics.G_L, cfg.vibration)
    first = hinf_cache.cached_synthesis(cfg.dynamics.G_L, cfg.vibration)
    again = hinf_cache.cached_synthesis(cfg.dynamics.G_L, cfg.vibration)
    assert len(made) == 1 and len(list(folder.glob("*.npz"))) == 1
    _same_design(fresh, first, timings=False)   # another synthesis takes another time
    _same_design(first, again)


def test_any_change_of_plant_or_weight_misses(paper_config, cache):
    folder, made = cache
    G_L, vib = paper_config.dynamics.G_L, paper_config.vibration
    hinf_cache.cached_synthesis(G_L, vib)
    e = G_L.entries
    nudged = FactoredTF(np.nextafter(e[0][0].gain, np.inf), e[0][0].num, e[0][0].den)
    G2 = TFMatrix(((nudged, *e[0][1:]), *e[1:]))
    keys = {hinf_cache.design_key(G_L, vib), hinf_cache.design_key(G2, vib),
            hinf_cache.design_key(G_L, dataclasses.replace(vib, t_r=vib.t_r * 1.01)),
            hinf_cache.design_key(G_L, dataclasses.replace(vib, order=vib.order - 1)),
            hinf_cache.design_key(G_L, dataclasses.replace(vib, W2=tuple(w * 2 for w in vib.W2)))}
    assert len(keys) == 5
    hinf_cache.cached_synthesis(G_L, dataclasses.replace(vib, order=vib.order - 1))
    assert len(made) == 2


def test_a_damaged_entry_is_synthesised_and_written_again(paper_config, cache):
    folder, made = cache
    G_L, vib = paper_config.dynamics.G_L, paper_config.vibration
    good = hinf_cache.cached_synthesis(G_L, vib)
    (entry,) = folder.glob("*.npz")
    entry.write_bytes(entry.read_bytes()[:100])   # truncated
    again = hinf_cache.cached_synthesis(G_L, vib)
    assert len(made) == 2
    _same_design(good, again, timings=False)
    hinf_cache.cached_synthesis(G_L, vib)
    assert len(made) == 2   # the entry written again is whole


def test_off_writes_nothing(paper_config, cache, monkeypatch):
    folder, made = cache
    monkeypatch.setenv(hinf_cache.CACHE_ENV, "off")
    hinf_cache.cached_synthesis(paper_config.dynamics.G_L, paper_config.vibration)
    hinf_cache.cached_synthesis(paper_config.dynamics.G_L, paper_config.vibration)
    assert len(made) == 2 and not folder.exists()


def test_the_cascade_is_built_from_the_cache(paper_config, cache):
    folder, made = cache
    a = CompensatorCascade(paper_config)
    b = CompensatorCascade(paper_config)
    assert len(made) == 1
    _same_design(a.design, b.design)
    ref = np.tile([5e-6, -3e-6], (400, 1))
    assert a.process(ref).tobytes() == b.process(ref).tobytes()
