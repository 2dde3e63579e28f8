"""The fit request's arrays travel as bytes (tactiled.pipeline.worker_packing) and come back equal."""

import pickle

import numpy as np

from tactiled.pipeline.worker_packing import dumps, pack_array, unpack_array


def test_arrays_round_trip_exactly_through_a_pickled_message() -> None:
    rng = np.random.default_rng(3)
    strain = rng.normal(0.0, 1e-3, (16, 16))
    strain.flags.writeable = False  # the pipeline's frames are read-only
    mask = rng.random((8, 8)) < 0.8
    transposed = strain.T  # not C-contiguous
    message = ("fit", 7, 2, pack_array(strain), "auto", pack_array(mask), None, 0.5, "lin",
               pack_array(transposed), pack_array(None))
    back = pickle.loads(dumps(message))
    got_strain, got_mask, got_t = (unpack_array(back[i]) for i in (3, 5, 9))
    assert got_strain.dtype == np.float64 and got_strain.shape == (16, 16)
    np.testing.assert_array_equal(got_strain, strain)
    assert got_mask.dtype == np.bool_
    np.testing.assert_array_equal(got_mask, mask)
    np.testing.assert_array_equal(got_t, transposed)
    assert unpack_array(back[10]) is None
    got_strain[0, 0] = 1.0  # the worker gets an array of its own
    assert strain[0, 0] != 1.0
