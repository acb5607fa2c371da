"""The resynthesis written in blocks against the whole-array resynthesise() and reed_openings()."""

import numpy as np
import pytest
import soundfile

from mpipe.core.signals import NpzStream, open_npz
from mpipe.inversion.output import resynthesis as rs
from mpipe.inversion.output import resynthesis_stream as rss
from mpipe.inversion.preparation.segments import reed_openings
from mpipe.inversion.settings import InversionConfig
from tests.inversion.output.test_resynthesis import FS, TABLE1, setup, table_of  # noqa: F401


@pytest.mark.parametrize("block", [1999, 7000, 2**20])
def test_blocks_give_the_whole_arrays(setup, tmp_path, block):  # noqa: F811
    kernel, _, sim = setup
    # overlapping windows (a later row overwrites), one failed, blocks crossing windows
    table = table_of(TABLE1, [27000, 28500, 30000, 32000])
    table.loc[2, "error"] = "no estimate"
    with NpzStream(tmp_path / "mp.npz") as out:
        out.add("p", sim.p)
        out.add("u", sim.u)
    disk = open_npz(tmp_path / "mp.npz", lazy_bytes=0)
    config = InversionConfig()
    path = tmp_path / "resynthesis.npz"
    rss.resynthesise_to_npz(path, table, disk["p"], disk["u"], FS, kernel, config, False,
                            block=block)  # fmt: skip
    whole = rs.resynthesise(table, sim.p, sim.u, FS, kernel, config, zero_mean=False)
    _, h = reed_openings(table, sim.p, FS)
    with np.load(path) as got:
        np.testing.assert_array_equal(got["p"], whole.p)
        np.testing.assert_array_equal(got["u"], whole.u)
        np.testing.assert_array_equal(got["h"], h)
        assert float(got["fs"]) == FS
    res = open_npz(path, lazy_bytes=0)
    mask = np.isfinite(whole.p)
    ratio = np.linalg.norm(sim.p[mask] - whole.p[mask]) / np.linalg.norm(sim.p[mask])
    np.testing.assert_allclose(rss.residual_ratio(disk["p"], res["p"]), ratio, rtol=1e-12)
    assert rss.resynthesised_samples(res["p"]) == int(mask.sum())
    rss.write_wav_blocks(tmp_path / "b.wav", res["p"], FS)
    rs.write_wav(tmp_path / "w.wav", whole.p, FS)
    np.testing.assert_array_equal(soundfile.read(tmp_path / "b.wav")[0],
                                  soundfile.read(tmp_path / "w.wav")[0])  # fmt: skip
