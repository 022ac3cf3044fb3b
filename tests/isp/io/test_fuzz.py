"""Fuzzing the reader and the pipeline with mutated DNGs (kind: property).

A small valid DNG (our writer: CFA, levels, dual-illuminant colour, a
NoiseProfile, four GainMaps and a WarpRectilinear) is mutated where a
malformed file hurts most: tag values, tag counts and types, and the bytes
of the opcode lists. Whatever comes, ``read_raw`` + the default pipeline
either work or raise :class:`isp.IspError` (one line for the user): no
other exception, no NaN reaching the output, no hang. The default suite
runs a short campaign; ``-m slow`` runs 10,000 inputs.
"""

from __future__ import annotations

import struct
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from isp import CFA, CameraMeta, IspError, Pipeline
from isp.io.dng_write import write_dng
from isp.opcodes import AreaSpec, GainMap, WarpRectilinear
from isp.io.read import read_raw

H, W = 24, 32
MAX_SECONDS = 5.0


def _seed_dng(path) -> bytes:
    rng = np.random.default_rng(7)
    gm = tuple(GainMap.spanning_image(rng.uniform(1, 2, (5, 6, 1)).astype(np.float32),
                                      area=AreaSpec(i, j, H, W, 0, 1, 2, 2))
               for i in range(2) for j in range(2))
    warp = WarpRectilinear(radial=((1.0, 0.01, 0.0, 0.0),), tangential=((0.0, 0.0),))
    meta = CameraMeta(
        cfa=CFA.RGGB, black_level=np.full((2, 2, 1), 64.0), white_level=(1023.0,),
        color_matrix_1=np.array([[0.7, -0.1, -0.05], [-0.4, 1.2, 0.2], [-0.1, 0.2, 0.6]]),
        color_matrix_2=np.array([[0.9, -0.3, -0.1], [-0.45, 1.25, 0.2], [-0.05, 0.15, 0.55]]),
        forward_matrix_1=np.array([[0.6, 0.3, 0.06], [0.25, 0.8, -0.05], [0.02, -0.2, 1.0]]),
        calibration_illuminant_1=21, calibration_illuminant_2=17,
        as_shot_neutral=(0.5, 1.0, 0.6), baseline_exposure=0.5, noise_profile=((1e-4, 1e-6),),
        opcodes={2: gm, 3: (warp,)}, default_crop=(2, 2, W - 4, H - 4), active_area=(0, 0, H, W),
    )
    data = rng.integers(64, 1023, (H, W)).astype(np.uint16)
    write_dng(path, data, meta)
    return path.read_bytes()


class Seed(tuple):
    """(dng bytes, tag entries) with a short repr for failure reports."""

    def __repr__(self):
        return f"<seed DNG, {len(self[0])} bytes, {len(self[1])} tags>"


@pytest.fixture(scope="module")
def seed(tmp_path_factory):
    p = tmp_path_factory.mktemp("fuzz") / "seed.dng"
    blob = _seed_dng(p)
    import tifffile

    with tifffile.TiffFile(p) as tif:
        page = tif.pages[0]
        # (entry offset in the IFD, value offset, value byte size) per tag
        entries = []
        ifd = page.offset
        n = struct.unpack("<H", blob[ifd:ifd + 2])[0]
        for k in range(n):
            e = ifd + 2 + 12 * k
            tag, typ, count = struct.unpack("<HHI", blob[e:e + 8])
            size = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8}.get(typ, 1) * count
            voff = e + 8 if size <= 4 else struct.unpack("<I", blob[e + 8:e + 12])[0]
            entries.append((tag, e, voff, size))
    return Seed((blob, entries))


def _process(path) -> None:
    t0 = time.perf_counter()
    try:
        frame = read_raw(path)
        out = Pipeline.default().without("jpeg").run(frame)
        assert np.isfinite(out.data).all(), "non-finite values reached the display image"
        assert out.data.min() >= 0 and out.data.max() <= 1
    except IspError as e:
        msg = str(e)
        assert "\n" not in msg and msg.startswith(str(path)) or "stage" in msg, msg
    assert time.perf_counter() - t0 < MAX_SECONDS, "too slow: a hang in the making"


def _mutate(blob: bytes, entries, choice: int, kind: int, payload: bytes, value: int) -> bytes:
    b = bytearray(blob)
    tag, e, voff, size = entries[choice % len(entries)]
    if kind == 0:      # overwrite (part of) the tag's value
        for i, byte in enumerate(payload[:max(size, 1)]):
            if voff + i < len(b):
                b[voff + i] = byte
    elif kind == 1:    # the tag's count
        b[e + 4:e + 8] = struct.pack("<I", value)
    elif kind == 2:    # the tag's type
        b[e + 2:e + 4] = struct.pack("<H", value % 20)
    elif kind == 3:    # the tag's value offset / inline value
        b[e + 8:e + 12] = struct.pack("<I", value)
    else:              # flip bits inside an opcode list (51008, 51009, 51022)
        ops = [x for x in entries if x[0] in (51008, 51009, 51022)]
        _, _, voff, size = ops[choice % len(ops)]
        for i, byte in enumerate(payload):
            pos = voff + (value + 7 * i) % max(size, 1)
            b[pos] ^= byte or 0x01
    return bytes(b)


mutation = st.tuples(st.integers(0, 10_000), st.integers(0, 4), st.binary(min_size=1, max_size=16),
                     st.one_of(st.integers(0, 2 ** 32 - 1), st.sampled_from([0, 1, 2, 3, 4, 9, 0xFFFFFFFF])))


def _run_campaign(seed, tmp_path, m):
    blob, entries = seed
    path = tmp_path / "fuzzed.dng"
    path.write_bytes(_mutate(blob, entries, *m))
    _process(path)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(m=mutation)
def test_fuzz_short(seed, tmp_path, m):
    _run_campaign(seed, tmp_path, m)


@pytest.mark.slow
@settings(max_examples=10_000, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(m=mutation)
def test_fuzz_long(seed, tmp_path, m):
    _run_campaign(seed, tmp_path, m)


def test_seed_itself_processes(seed, tmp_path):
    path = tmp_path / "seed.dng"
    path.write_bytes(seed[0])
    frame = read_raw(path)
    assert any("WarpRectilinear skipped" in n for n in frame.meta.notes)
    _process(path)
