"""What is kept on disk outside the checkout and made by rtsim's code is keyed by that code (rtsim.sources):
the generated kernel wrappers (tests/test_boundcall.py), the validation benchmark's generated runs (by the
generator package's code) and their truth (by all of it), so an edit never hands back an old result."""
from __future__ import annotations

import pytest

from rtsim import sources
from rtsim.validate import bench_truth
from rtsim.validate.fieldbench import generate


@pytest.fixture
def tree(tmp_path, monkeypatch):
    for rel in ("rtsim/a.py", "rtsim/sub/b.py", "bridge/c.py", "docs/d.py"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("x = 1\n")
    monkeypatch.setattr(sources, "ROOT", tmp_path)
    sources.sources_digest.cache_clear()
    yield tmp_path
    sources.sources_digest.cache_clear()


def test_the_digest_follows_every_source_file_and_nothing_else(tree):
    whole, sub = sources.sources_digest(), sources.sources_digest("rtsim/sub")
    sources.sources_digest.cache_clear()
    (tree / "docs/d.py").write_text("x = 2\n")                     # not a source tree
    assert sources.sources_digest() == whole
    sources.sources_digest.cache_clear()
    (tree / "rtsim/a.py").write_text("x = 2\n")
    assert sources.sources_digest() != whole and sources.sources_digest("rtsim/sub") == sub
    sources.sources_digest.cache_clear()
    (tree / "rtsim/sub/b.py").rename(tree / "rtsim/sub/e.py")       # a moved file, same text
    assert sources.sources_digest("rtsim/sub") != sub


def test_benchmark_runs_and_truth_are_keyed_by_the_code_that_makes_them(tmp_path, monkeypatch):
    case, car = {"id": "c000", "speed": 20.0}, {"mass": 1000.0}
    made = {}

    def truth(*args):
        made["n"] = made.get("n", 0) + 1
        return {"id": case["id"], "effects": []}
    monkeypatch.setattr(bench_truth, "truth", truth)
    runs = generate.key(case, car)
    bench_truth.cached_truth(case, car, None, None, root=tmp_path)
    bench_truth.cached_truth(case, car, None, None, root=tmp_path)
    assert made["n"] == 1                                            # cached

    monkeypatch.setattr(bench_truth, "sources_digest", lambda *trees: b"rtsim edited")
    assert generate.key(case, car) == runs                           # the generator's code is unchanged
    bench_truth.cached_truth(case, car, None, None, root=tmp_path)
    assert made["n"] == 2                                            # the model that replays them changed

    monkeypatch.setattr(generate, "code_digest", lambda: "generator edited")
    assert generate.key(case, car) != runs
