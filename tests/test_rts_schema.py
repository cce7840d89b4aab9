import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from seesys.core import rts_schema


def test_channel_names_unique_and_unknown_names_named():
    assert len(set(rts_schema.CHANNEL_NAMES)) == rts_schema.NUM_CHANNELS
    with pytest.raises(KeyError, match="unknown RTS channel 'nope'; channels are brightness, contrast"):
        rts_schema.index_of("nope")


def test_a_reordered_schema_of_the_same_size_is_refused():
    channels = list(rts_schema.CHANNELS)
    channels[7], channels[8] = channels[8], channels[7]  # rel_tx <-> rel_ty: same count, other meaning
    reordered = rts_schema.fingerprint(tuple(channels))
    assert reordered != rts_schema.FINGERPRINT
    with pytest.raises(rts_schema.SchemaMismatch, match=f"model.onnx uses RTS schema v{rts_schema.SCHEMA_VERSION}"):
        rts_schema.check_compatible(rts_schema.SCHEMA_VERSION, reordered, "model.onnx")
    rts_schema.check_compatible(rts_schema.SCHEMA_VERSION, rts_schema.FINGERPRINT, "this build")


def test_changing_the_channels_without_a_new_version_fails_at_import(tmp_path, monkeypatch):
    source = Path(rts_schema.__file__).read_text()
    contrast = source.index('"contrast",')
    scale = source.index("0.25", contrast)  # contrast's scale, the first number after its name
    changed = source[:scale] + "0.3" + source[scale + len("0.25") :]
    assert changed != source
    path = tmp_path / "rts_schema_changed.py"
    path.write_text(changed)
    spec = importlib.util.spec_from_file_location("rts_schema_changed", path)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "rts_schema_changed", module)
    with pytest.raises(RuntimeError, match="bump SCHEMA_VERSION"):
        spec.loader.exec_module(module)


def test_normalise_applies_transform_and_scale_and_zeroes_nan():
    row = np.zeros(rts_schema.NUM_CHANNELS)
    row[rts_schema.index_of("contrast")] = 0.125
    row[rts_schema.index_of("laplacian")] = np.e - 1
    row[rts_schema.index_of("rel_yaw")] = np.nan
    out = rts_schema.normalise(row[None, :])
    assert out.dtype == np.float32 and out.shape == (1, rts_schema.NUM_CHANNELS)
    assert out[0, rts_schema.index_of("contrast")] == pytest.approx(0.5)
    assert out[0, rts_schema.index_of("laplacian")] == pytest.approx(0.1)
    assert out[0, rts_schema.index_of("rel_yaw")] == 0.0
    with pytest.raises(ValueError, match="channels"):
        rts_schema.normalise(np.zeros((2, 3)))


def test_values_replaced_by_zero_are_counted_per_row():
    rows = np.ones((2, 3, rts_schema.NUM_CHANNELS))
    rows[0, 1, rts_schema.index_of("rel_yaw")] = np.nan
    rows[0, 1, rts_schema.index_of("avg_mp_depth")] = np.inf
    rows[1, 2, rts_schema.index_of("var_mp_depth")] = -np.inf  # log1p(max(-inf, 0)) = 0: a value, not replaced
    rows[1, 0, rts_schema.index_of("contrast")] = -np.inf
    out, replaced = rts_schema.normalise_counted(rows)
    assert replaced.tolist() == [[0, 2, 0], [1, 0, 0]]
    assert np.isfinite(out).all()
    np.testing.assert_array_equal(out, rts_schema.normalise(rows))


def test_normalise_is_each_channels_transform_and_scale_value_by_value():
    """Every channel's transform (log1p of the value clipped at 0, signed log1p, none) and scale, on values of every
    magnitude and sign with NaN and ±inf among them, and a model's columns taken after: as written out one value at a
    time; each value without a finite result is 0 and counted in its row."""
    rng = np.random.default_rng(4)
    shape = (6, 5, rts_schema.NUM_CHANNELS)
    rows = rng.normal(size=shape) * 10.0 ** rng.uniform(-4, 4, shape)
    for value, share in ((np.nan, 0.05), (np.inf, 0.02), (-np.inf, 0.02), (-0.0, 0.02)):
        rows[rng.random(rows.shape) < share] = value
    columns = np.array([7, 0, 3, *range(8, rts_schema.NUM_CHANNELS, 2)])
    expected = np.zeros(rows.shape[:-1] + (len(columns),))
    counts = np.zeros(rows.shape[:-1], dtype=int)
    for index in np.ndindex(rows.shape[:-1]):
        for k, c in enumerate(columns):
            channel, v = rts_schema.CHANNELS[c], rows[index][c]
            with np.errstate(invalid="ignore"):
                if channel.transform == "log1p":
                    v = np.log1p(max(v, 0.0)) if not np.isnan(v) else v
                elif channel.transform == "signed_log1p":
                    v = np.sign(v) * np.log1p(abs(v))
            v = v / channel.scale
            expected[index + (k,)] = v if np.isfinite(v) else 0.0
            counts[index] += not np.isfinite(v)
    out, replaced = rts_schema.normalise_counted(rows, columns)
    assert out.dtype == np.float32 and out.shape == expected.shape
    np.testing.assert_allclose(out, expected.astype(np.float32), rtol=1e-6, atol=0)
    np.testing.assert_array_equal(replaced, counts)
    assert {"identity", "log1p"} <= {rts_schema.CHANNELS[c].transform for c in columns}  # both kinds are covered


def test_a_model_takes_its_own_channels_from_a_later_schemas_rows():
    """A model records its input channels by name and fingerprint: one made with the first 16 channels (schema v1)
    takes those columns of today's rows; a channel unknown here, or defined otherwise, is refused by name."""
    v1 = rts_schema.CHANNELS[:16]
    names = [c.name for c in v1]
    assert rts_schema.fingerprint(v1) == 0x272A99E0  # schema v1's channels, unchanged in later versions
    assert list(rts_schema.columns_of(names, 0x272A99E0, "old.onnx")) == list(range(16))
    reordered = [names[1], names[0]]
    columns = rts_schema.columns_of(reordered, rts_schema.fingerprint((v1[1], v1[0])), "x")
    assert list(columns) == [1, 0]
    with pytest.raises(
        rts_schema.SchemaMismatch, match="model.onnx takes RTS channels this SEESys does not have: sonar_range"
    ):
        rts_schema.columns_of([*names, "sonar_range"], 0, "model.onnx")
    # Schema v3 replaced v2's per-frame depth_edge_offset: a model that took it is refused, not fed the new channel.
    v2_names = [*names, "depth_holes", "depth_noise", "depth_edge_offset"]
    with pytest.raises(rts_schema.SchemaMismatch, match="does not have: depth_edge_offset"):
        rts_schema.columns_of(v2_names, 0xC231583F, "v2.onnx")
    with pytest.raises(
        rts_schema.SchemaMismatch, match="model.onnx takes RTS channels brightness, contrast defined otherwise"
    ):
        rts_schema.columns_of(names[:2], 0x1234, "model.onnx")
    rows = np.arange(2 * rts_schema.NUM_CHANNELS, dtype=np.float64).reshape(2, -1)
    rows[0, rts_schema.index_of("depth_noise")] = np.nan  # not among the model's channels: not counted
    rows[1, rts_schema.index_of("contrast")] = np.nan
    kept, replaced = rts_schema.normalise_counted(rows, columns)
    assert kept.shape == (2, 2) and list(replaced) == [0, 1]
