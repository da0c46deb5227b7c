"""A batch worker parses each TOML file once (rtsim.configfile.keeping_tables) and gives every load its
own copy of the table: equal to a fresh parse, overrides applied to that copy only, no table or array
shared with the kept one or with another load's."""
from __future__ import annotations

import datetime
from pathlib import Path

from rtsim.configfile import keeping_tables, load_toml, overrides

ROOT = Path(__file__).resolve().parents[1]


def _containers(value, out: list) -> list:
    if isinstance(value, (dict, list)):
        out.append(value)
        for v in (value.values() if isinstance(value, dict) else value):
            _containers(v, out)
    return out


def test_each_load_gets_its_own_copy_of_the_kept_table(tmp_path):
    src = tmp_path / "t.toml"
    src.write_text('a = 1\nwhen = 2026-11-28T15:00:00Z\n[b]\nc = [1.5, [2, 3], {d = "x"}]\n'
                   '[[e]]\nf = 0.25\n[[e]]\nf = -0.5\n')
    fresh = load_toml(src)
    kept: dict = {}
    with keeping_tables(kept):
        first = load_toml(src)
        with overrides({src.resolve(): {"b.c": [9.0], "e": [{"f": 1.0}]}}):
            changed = load_toml(src)
        second = load_toml(src)
    assert first == fresh == second and isinstance(first["when"], datetime.datetime)
    assert changed["b"]["c"] == [9.0] and changed["e"] == [{"f": 1.0}]
    first["b"]["c"][1].append(4)
    first["e"][0]["f"] = 7.0
    assert second == fresh and kept[src.resolve()] == fresh
    ids = {id(c) for c in _containers(kept[src.resolve()], [])}
    for table in (first, changed, second):
        assert not ids & {id(c) for c in _containers(table, [])}


def test_a_vehicle_file_loads_alike_kept_or_not():
    car = ROOT / "configs" / "vehicles" / "eps_car.toml"
    with keeping_tables({}):
        assert [load_toml(car) for _ in range(2)] == [load_toml(car)] * 2
    assert load_toml(car) == _fresh(car)


def _fresh(path: Path) -> dict:
    import tomllib

    with path.open("rb") as fh:
        return tomllib.load(fh)
