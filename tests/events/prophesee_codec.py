"""Tiny Prophesee encoders for tests: known events -> RAW (EVT 2.0 / 3.0) or DAT bytes.

Written from the published word layouts (see rdnet/events/io/prophesee.py); a Python
loop per event is fine here (a few thousand events)."""
from __future__ import annotations

import struct

import numpy as np

from rdnet.events import EVENT_DTYPE


def known_events(rng: np.random.Generator, n: int, width: int, height: int, t0: int, t1: int) -> np.ndarray:
    """Random events sorted by (t, y, p, x) (the order an EVT 3.0 vector decodes in),
    with runs sharing (t, y, p) so that the EVT 3.0 encoder uses vectors."""
    base = rng.integers(0, n // 4 + 1, n)
    a = np.empty(n, EVENT_DTYPE)
    a["t"] = np.sort(rng.integers(t0, t1, n // 4 + 1))[base]
    a["y"] = rng.integers(0, height, n // 4 + 1)[base]
    a["p"] = rng.integers(0, 2, n // 4 + 1)[base]
    a["x"] = rng.integers(0, width, n)
    a = np.unique(a)               # no duplicate events: vectors cannot repeat a pixel
    return a[np.lexsort((a["x"], a["p"], a["y"], a["t"]))]


def encode_evt2(ev: np.ndarray, header: str, vendor_every: int = 50) -> bytes:
    words, th = [], None
    for i, e in enumerate(ev):
        t = int(e["t"])
        if th != t >> 6:
            th = t >> 6
            words.append((0x8 << 28) | (th & 0x0FFFFFFF))
        words.append((int(e["p"]) << 28) | ((t & 0x3F) << 22) | (int(e["x"]) << 11) | int(e["y"]))
        if vendor_every and i % vendor_every == 0:
            words.append((0xA << 28) | 0x123)              # EXT_TRIGGER: skipped
    return header.encode() + struct.pack(f"<{len(words)}I", *words)


def encode_evt3(ev: np.ndarray, header: str) -> bytes:
    words: list[int] = []
    th = tl = y = None
    i, n = 0, len(ev)
    while i < n:
        t, yy, p = int(ev["t"][i]), int(ev["y"][i]), int(ev["p"][i])
        j = i
        while j < n and int(ev["t"][j]) == t and int(ev["y"][j]) == yy and int(ev["p"][j]) == p:
            j += 1
        h = t >> 12
        if th is None:
            words.append((0x8 << 12) | (h & 0xFFF))
        else:
            for step in range(th + 1, h + 1):                # every time-high step, as a camera does
                words.append((0x8 << 12) | (step & 0xFFF))
        th = h
        if tl != (t & 0xFFF) or len(words) and words[-1] >> 12 == 0x8:
            tl = t & 0xFFF
            words.append((0x6 << 12) | tl)
        if y != yy:
            y = yy
            words.append(yy)
        xs = [int(v) for v in ev["x"][i:j]]
        if len(xs) == 1:
            words.append((0x2 << 12) | (p << 11) | xs[0])
        else:
            base = xs[0]
            words.append((0x3 << 12) | (p << 11) | base)
            while xs:
                nb = 8 if max(xs) - base < 8 else 12
                mask = 0
                for x in [v for v in xs if v - base < nb]:
                    mask |= 1 << (x - base)
                xs = [v for v in xs if v - base >= nb]
                words.append(((0x5 if nb == 8 else 0x4) << 12) | mask)
                base += nb
            words.append(0xE << 12)                          # OTHERS: skipped
        i = j
    return header.encode() + struct.pack(f"<{len(words)}H", *words)


def encode_dat(ev: np.ndarray, width: int, height: int) -> bytes:
    head = f"% Data file containing CD events\n% Version 2\n% Width {width}\n% Height {height}\n"
    rec = np.empty(len(ev), [("t", "<u4"), ("d", "<u4")])
    rec["t"] = ev["t"].astype(np.int64) & 0xFFFFFFFF
    rec["d"] = ev["x"].astype(np.uint32) | (ev["y"].astype(np.uint32) << 14) | (ev["p"].astype(np.uint32) << 28)
    return head.encode() + bytes([0x0C, 8]) + rec.tobytes()
