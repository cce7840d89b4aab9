import numpy as np
import pytest

from seesys.protocol import rts_schema


def test_channel_names_unique_and_indexed():
    assert len(set(rts_schema.CHANNEL_NAMES)) == rts_schema.NUM_CHANNELS
    for i, name in enumerate(rts_schema.CHANNEL_NAMES):
        assert rts_schema.index_of(name) == i
    with pytest.raises(KeyError, match="unknown RTS channel"):
        rts_schema.index_of("nope")


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
