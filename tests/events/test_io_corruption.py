"""Truncated or bit-flipped files must give a FormatError naming the file, never another
exception type (nor a crash of the interpreter)."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from rdnet.errors import FormatError
from rdnet.events import Recording
from rdnet.events.io import H5EventReader, load, write_recording


def _outcomes(path, variants, load_fn):
    """Write each corrupted byte string to ``path`` and load it; return the count of
    FormatErrors. Any other exception fails the test."""
    errors = 0
    for data in variants:
        path.write_bytes(data)
        try:
            load_fn(path)
        except FormatError as e:
            assert str(path) in str(e)
            errors += 1
    return errors


def _truncations(data: bytes, n: int) -> list[bytes]:
    cuts = np.linspace(0, len(data) - 1, n).astype(int)
    return [data[:c] for c in cuts]


def _flips(data: bytes, rng: np.random.Generator, n: int, per_variant: int, lo: int = 0,
           hi: int | None = None) -> list[bytes]:
    hi = len(data) if hi is None else hi
    out = []
    for _ in range(n):
        b = bytearray(data)
        for pos in rng.integers(lo, hi, per_variant):
            b[pos] ^= int(rng.integers(1, 256))
        out.append(bytes(b))
    return out


@pytest.fixture
def h5_bytes(tmp_path, make_recording):
    rec = make_recording(30_000, 3)
    src = tmp_path / "src.h5"
    write_recording(src, rec, chunk_events=4096)
    return src.read_bytes()


def _load_and_slice(path):
    load(path)
    with H5EventReader(path) as r:
        r.slice_time(200_000, 400_000)


def test_truncated_hdf5(tmp_path, h5_bytes):
    variants = _truncations(h5_bytes, 12)
    assert _outcomes(tmp_path / "bad.h5", variants, _load_and_slice) == len(variants)


def test_bit_flipped_hdf5(tmp_path, h5_bytes):
    rng = np.random.default_rng(0)
    variants = _flips(h5_bytes, rng, 25, 4) + _flips(h5_bytes, rng, 25, 1, hi=4096)   # data and metadata
    errors = _outcomes(tmp_path / "bad.h5", variants, _load_and_slice)
    assert errors >= 20


def test_truncated_aedat4(tmp_path, davis346_path):
    variants = _truncations(davis346_path.read_bytes(), 10)
    assert _outcomes(tmp_path / "bad.aedat4", variants, load) == len(variants)


def test_bit_flipped_aedat4(tmp_path, davis346_path):
    data = davis346_path.read_bytes()
    rng = np.random.default_rng(1)
    # the header (~3 kB XML description) and the packet data
    variants = _flips(data, rng, 30, 1, hi=3200) + _flips(data, rng, 20, 30)
    errors = _outcomes(tmp_path / "bad.aedat4", variants, load)
    assert errors >= 25


def test_non_utf8_aedat4_header_is_a_format_error(tmp_path, davis346_path):
    """aedat 2.3 aborts the interpreter on such a header; the reader must catch it first."""
    data = bytearray(davis346_path.read_bytes())
    i = data.index(b"<dv version")
    data[i + 5] = 0xF1
    path = tmp_path / "bad.aedat4"
    path.write_bytes(bytes(data))
    with pytest.raises(FormatError, match="header"):
        load(path)


def test_truncated_and_flipped_text(tmp_path, ecd_path):
    data = ecd_path.read_bytes()[:100_000]
    rng = np.random.default_rng(2)
    path = tmp_path / "events.txt"
    trunc = _truncations(data, 10)
    # a cut leaving 1 to 3 numbers on the last line, or an empty file, must be an error
    expected = sum(1 for d in trunc if not d or 0 < len(d.rsplit(b"\n", 1)[-1].split()) < 4)
    assert expected >= 5
    assert _outcomes(path, trunc, lambda p: load(p, sensor_size=(240, 180))) >= expected
    flips = _flips(data, rng, 30, 3)
    assert _outcomes(path, flips, lambda p: load(p, sensor_size=(240, 180))) >= 15


def test_corrupt_npz(tmp_path, make_recording):
    from rdnet.events.io import write_npz
    src = tmp_path / "src.npz"
    write_npz(src, make_recording(5000, 2))
    data = src.read_bytes()
    rng = np.random.default_rng(3)
    variants = _truncations(data, 8) + _flips(data, rng, 20, 3)
    assert _outcomes(tmp_path / "bad.npz", variants, load) >= 20


def test_unreadable_file(tmp_path, make_recording):
    import os
    path = tmp_path / "r.h5"
    write_recording(path, make_recording(10))
    shutil.copy(path, tmp_path / "copy.h5")
    os.chmod(tmp_path / "copy.h5", 0)
    if os.access(tmp_path / "copy.h5", os.R_OK):       # running as root: permissions do not apply
        (tmp_path / "copy.h5").unlink()
        (tmp_path / "copy.h5").mkdir()               # a directory is unreadable as a file
    with pytest.raises(FormatError, match="copy.h5"):
        load(tmp_path / "copy.h5")
    assert isinstance(load(path), Recording)


# --- Prophesee RAW (EVT 2.0 / 3.0) and DAT ------------------------------------------------------
def _prophesee_files(tmp_path, rng):
    from prophesee_codec import encode_dat, encode_evt2, encode_evt3, known_events
    ev = known_events(rng, 2000, 320, 240, 1_000, 30_000_000)
    head2, head3 = "% evt 2.0\n% geometry 320x240\n", "% evt 3.0\n% geometry 320x240\n"
    dat = encode_dat(ev, 320, 240)
    # (bytes, suffix, word size, first data byte)
    return {"evt2": (encode_evt2(ev, head2), ".raw", 4, len(head2)),
            "evt3": (encode_evt3(ev, head3), ".raw", 2, len(head3)),
            "dat": (dat, ".dat", 8, dat.index(bytes([0x0C, 8])) + 2)}


def _read_all(path):
    from rdnet.events.io import open_events
    load(path)
    with open_events(path) as s:
        for _ in s.chunks(500):
            pass


@pytest.mark.parametrize("enc", ["evt2", "evt3", "dat"])
def test_truncated_prophesee_mid_word(tmp_path, enc):
    data, suffix, wb, start = _prophesee_files(tmp_path, np.random.default_rng(4))[enc]
    n_words = (len(data) - start) // wb
    cuts = [start + k * wb + r for k in np.linspace(0, n_words - 1, 8).astype(int) for r in range(1, wb)]
    path = tmp_path / f"bad{suffix}"
    assert _outcomes(path, [data[:c] for c in cuts], _read_all) == len(cuts)
    path.write_bytes(data[:cuts[0]])
    with pytest.raises(FormatError, match="truncated"):
        load(path)


@pytest.mark.parametrize("enc", ["evt2", "evt3", "dat"])
def test_garbage_words_and_flipped_header_prophesee(tmp_path, enc):
    data, suffix, _, start = _prophesee_files(tmp_path, np.random.default_rng(5))[enc]
    mid = start + (len(data) - start) // 2 // 8 * 8
    garbage = data[:mid] + b"\x99" * 64 + data[mid + 64:]     # undefined word types / x out of range
    if enc == "dat":
        flipped = [data.replace(b"% Version 2", b"% Version 6", 1), data.replace(b"Width 320", b"Width 3?0", 1),
                   data[:start - 2] + b"\x0e" + data[start - 1:]]          # event type: triggers, not CD
    else:
        flipped = [data.replace(b"% evt", b"% xvt", 1), data.replace(b"320x240", b"32?x240", 1),
                   data.replace(b"320x240", b"320x24\xf0", 1)]
    path = tmp_path / f"bad{suffix}"
    assert _outcomes(path, [garbage] + flipped, _read_all) == 1 + len(flipped)
    path.write_bytes(garbage)
    with pytest.raises(FormatError, match="byte"):
        load(path)


def test_bit_flipped_prophesee_real_file(tmp_path, night_path):
    """Random flips in a real EVT 3.0 file: a FormatError or a valid decode, nothing else
    (a flipped bit inside a valid word can give another valid word); most are caught."""
    data = night_path.read_bytes()[:200_000]
    data = data[:len(data) - (len(data) - 225) % 2]
    rng = np.random.default_rng(6)
    variants = _flips(data, rng, 30, 40, lo=225)
    errors = _outcomes(tmp_path / "bad.raw", variants, _read_all)
    assert errors >= 15
