"""nifo fleet's inputs: manifests (CSV, YAML) and folder trees, and their errors."""

from __future__ import annotations

from pathlib import Path

import pytest

from nifo.fleet.cache import cache_key, content_hash, load_partial, settings_hash, store_partial
from nifo.fleet.manifest import load_fleet_input, load_manifest, scan_tree
from nifo_core.errors import ConfigError


def _touch(p: Path) -> Path:
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(b"\x89MCAP0\r\n")
    return p


def test_csv_manifest_rows_become_entries_with_paths_relative_to_the_manifest(tmp_path):
    (tmp_path / "m.csv").write_text("Vehicle,corner,date,path,m2_kg\nA,FL,2026-01-02,a/1.mcap,301.5\n"
                                    "B,,,b/1.mcap,\n")
    e = load_manifest(tmp_path / "m.csv")
    assert [x.group for x in e] == [("A", "FL"), ("B", "-")]
    assert e[0].path == tmp_path / "a" / "1.mcap" and e[0].m2_kg == 301.5 and e[1].m2_kg is None


def test_yaml_manifest_and_per_group_model(tmp_path):
    (tmp_path / "m.yaml").write_text("bags:\n  - {vehicle: A, corner: RR, path: x.mcap, model: s.yaml}\n"
                                     "  - {vehicle: A, corner: RR, path: y.mcap, model: s.yaml}\n")
    e = load_fleet_input(tmp_path / "m.yaml")
    assert {x.model for x in e} == {tmp_path / "s.yaml"}


@pytest.mark.parametrize("text, match", [
    ("vehicle,path,colour\nA,x.mcap,red\n", r"line 2: unknown column\(s\) \['colour'\]"),
    ("vehicle,path\n,x.mcap\n", "line 2: vehicle: Field required"),
    ("vehicle,path,m2_kg\nA,x.mcap,-3\n", "line 2: m2_kg: Value error, -3.0 must be a sprung mass"),
    ("vehicle,path\nA,x.mcap\nB,x.mcap\n", "listed twice"),
    ("vehicle,path\n", "lists no bags"),
])
def test_bad_manifests_name_the_line_and_the_fix(tmp_path, text, match):
    (tmp_path / "m.csv").write_text(text)
    with pytest.raises(ConfigError, match=match) as info:
        load_manifest(tmp_path / "m.csv")
    assert str(tmp_path / "m.csv") in str(info.value)


def test_a_group_needs_one_model_and_one_mass(tmp_path):
    (tmp_path / "m.csv").write_text("vehicle,path,model\nA,x.mcap,a.yaml\nA,y.mcap,b.yaml\n")
    with pytest.raises(ConfigError, match="two model files"):
        load_fleet_input(tmp_path / "m.csv")
    (tmp_path / "n.csv").write_text("vehicle,path\nA,x.mcap\n")
    with pytest.raises(ConfigError, match="no model file.*Fix: give --model"):
        load_fleet_input(tmp_path / "n.csv")
    (tmp_path / "k.csv").write_text("vehicle,path,m2_kg\nA,x.mcap,300\nA,y.mcap,310\n")
    with pytest.raises(ConfigError, match="two sprung masses"):
        load_fleet_input(tmp_path / "k.csv", default_model=tmp_path / "s.yaml")


def test_folder_tree_with_and_without_corners(tmp_path):
    _touch(tmp_path / "v1" / "FL" / "r1.mcap")
    _touch(tmp_path / "v1" / "FL" / "r2.mcap")
    (tmp_path / "v1" / "FL" / "r1.mcap.truth.json").write_text("{}")
    bag = tmp_path / "v2" / "run_a"
    bag.mkdir(parents=True)
    (bag / "metadata.yaml").write_text("x")
    _touch(bag / "run_a_0.mcap")
    e = scan_tree(tmp_path)
    assert [(x.vehicle, x.corner, x.path.name) for x in e] == [("v1", "FL", "r1.mcap"), ("v1", "FL", "r2.mcap"),
                                                              ("v2", "-", "run_a")]
    with pytest.raises(ConfigError, match="no bags found"):
        scan_tree(tmp_path / "v1" / "FL")


def test_cache_key_follows_content_and_settings_not_the_name(tmp_path):
    a = tmp_path / "a.mcap"
    a.write_bytes(b"abc" * 1000)
    b = tmp_path / "b.mcap"
    b.write_bytes(b"abc" * 1000)
    s1, s2 = settings_hash({"block": 6144}), settings_hash({"block": 4096})
    assert content_hash(a) == content_hash(b)
    assert cache_key(content_hash(a), s1) != cache_key(content_hash(a), s2)
    b.write_bytes(b"abc" * 999 + b"abd")
    assert content_hash(a) != content_hash(b)


def test_cache_round_trip_is_atomic_and_a_torn_entry_reads_as_absent(tmp_path):
    import numpy as np

    key = "ab" + "0" * 38
    store_partial(tmp_path, key, {"x": np.arange(3.0)}, {"n_samples": 3})
    got = load_partial(tmp_path, key)
    np.testing.assert_array_equal(got["state"]["x"], [0, 1, 2])
    assert got["info"] == {"n_samples": 3}
    assert not list(tmp_path.rglob("*.tmp"))
    (tmp_path / f"{key}.npz").write_bytes(b"PK\x03\x04 torn")
    assert load_partial(tmp_path, key) is None


def test_a_hermitian_stack_is_stored_as_its_upper_triangles_small_arrays_as_json_all_read_back_bit_for_bit(tmp_path):
    import numpy as np

    rng = np.random.default_rng(1)
    x = rng.normal(size=(7, 4, 50)) + 1j * rng.normal(size=(7, 4, 50))
    g = np.einsum("fak,fbk->fab", x, x.conj())          # exactly Hermitian, as accumulated
    g = (g + np.conj(np.swapaxes(g, 1, 2))) / 2
    skew = g.copy()
    skew[0, 0, 1] += 1e-3                               # not Hermitian: stored whole
    small = {"n": np.array(3), "fs": np.array(600.0 / 7), "names": np.array(["spindle", "body"]),
             "tail": np.zeros((4, 0)), "play": np.array([1e-300, -0.1])}
    store_partial(tmp_path, "cd" + "1" * 38, {"acc.sum": g, "other": skew, **small}, {})
    with np.load(tmp_path / ("cd" + "1" * 38 + ".npz")) as z:
        assert sorted(z.files) == ["__info__", "__small__", "state.other", "triu.4.acc.sum"]
        assert z["triu.4.acc.sum"].shape == (7, 10)
    got = load_partial(tmp_path, "cd" + "1" * 38)["state"]
    assert np.array_equal(got["acc.sum"], g) and np.array_equal(got["other"], skew)
    for k, v in small.items():      # small arrays: value, dtype and shape exactly
        assert got[k].dtype == v.dtype and got[k].shape == v.shape and np.array_equal(got[k], v), k
