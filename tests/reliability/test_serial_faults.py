"""Serial faults on a real pseudo-terminal, through the real daemon.

A :class:`~tactiled.pipeline.Daemon` reads a ``serial://`` sensor (pyserial on a pty, through
the ``pty_device`` fixture's stable symlink) with real fit workers, while the test plays the
device and damages the byte stream on purpose: garbage bursts between frames, bit flips at
1e-4 per bit, truncated frames, corrupted ``rows``/``cols`` bytes, and every split point of a
frame across reads.

What "delivered" means: the test knows which frames reached the wire intact (their own bytes
unchanged and the byte before them a ``0x00`` delimiter: a frame glued to unterminated garbage is
lost by design, docs/reference/protocol.md "Stream rules").  With latest-frame-wins, an intact frame need
not get an estimate of its own, so delivery is checked where it is defined: at the source, the
decoder must deliver exactly the intact frames (same seq, device time and counts, in order), and
the pipeline must account for each of them (``frames = published + superseded + ...``).  In
lossless mode every intact frame gets exactly one estimate.  And every estimate and zeroed frame
published must carry the seq/device time of a frame sent intact: no corrupt frame accepted.
"""

from __future__ import annotations

import random
import sys
import zlib
from dataclasses import dataclass, field

import numpy as np
import pytest
from rel_helpers import (
    TapDecoder,
    accounted,
    check_estimates,
    collect,
    figures,
    fingerprint,
    scene_frames,
    serial_url,
    wait_for,
    wait_open,
)

from tactiled.frames import HEADER, MAX_ENCODED_LEN, Frame, cobs_encode, encode_frame
from tactiled.pipeline import Daemon
from tactiled.settings import load_settings
from tactiled.sources import open_source

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="needs Linux ptys")

SENSOR = "index"
WIRE_ID = 5
BIT_ERROR_RATE = 1e-4
SEEDS = {"garbage": 11, "bitflip": 12, "truncated": 13, "length": 14, "mixed": 15}


# --------------------------------------------------------------------------------------------
# Building a damaged stream, knowing exactly which frames survive


@dataclass
class Wire:
    """The bytes to send and, for each frame, where its encoding (delimiter included) lies."""

    data: bytearray = field(default_factory=lambda: bytearray(b"\x00"))  # sender start-up 0x00
    spans: list[tuple[int, int]] = field(default_factory=list)
    damaged: set[int] = field(default_factory=set)  # frames whose own bytes were altered
    reshaped: dict[int, Frame] = field(default_factory=dict)  # sent well formed as 4x16
    faults: dict[str, int] = field(default_factory=dict)

    def count(self, kind: str) -> None:
        self.faults[kind] = self.faults.get(kind, 0) + 1

    def add(self, wire: bytes, damaged: bool = False) -> None:
        start = len(self.data)
        self.data += wire
        if damaged:
            self.damaged.add(len(self.spans))
        self.spans.append((start, len(self.data)))

    def flip_bits(self, rng: random.Random, rate: float) -> int:
        """Flip each bit with probability ``rate``; frames hit are marked damaged."""
        nbits = 8 * len(self.data)
        flips = np.random.default_rng(rng.getrandbits(32)).binomial(nbits, rate)
        hit = sorted(rng.randrange(nbits) for _ in range(flips))
        for bit in hit:
            self.data[bit // 8] ^= 1 << (bit % 8)
        starts = [s for s, _ in self.spans]
        for bit in hit:
            i = int(np.searchsorted(starts, bit // 8, side="right")) - 1
            if i >= 0 and bit // 8 < self.spans[i][1]:
                self.damaged.add(i)
        self.faults["bit_flips"] = self.faults.get("bit_flips", 0) + flips
        return flips

    def intact(self) -> list[int]:
        """Frames the receiver must deliver: unaltered, and starting right after a 0x00."""
        return [i for i, (s, _) in enumerate(self.spans)
                if i not in self.damaged and self.data[s - 1] == 0]

    def chunks(self) -> int:
        """Non-empty chunks between 0x00 bytes: each is one frame or one counted rejection."""
        return sum(1 for c in bytes(self.data).split(b"\x00") if c)

    def expected_resyncs(self, intact: set[int]) -> int:
        """Good frames that follow one or more rejected chunks (DecoderStats.resyncs)."""
        starts = {s: i for i, (s, _) in enumerate(self.spans)}
        resyncs, in_error, pos = 0, False, 0
        for chunk in bytes(self.data).split(b"\x00"):
            if chunk:
                i = starts.get(pos)
                if i is not None and i in intact:
                    resyncs += in_error
                    in_error = False
                else:
                    in_error = True
            pos += len(chunk) + 1
        return resyncs


def _garbage(rng: random.Random) -> bytes:
    n = rng.choice([1, 2, 5, 17, 64, 150, 301])
    data = bytes(rng.getrandbits(8) for _ in range(n))
    if rng.random() < 0.5:  # half the bursts end in a delimiter (cost nothing), half do not
        data = data.rstrip(b"\x00") + b"\x00"
    else:
        data = data.rstrip(b"\x00") or b"\x55"
    return data


def _with_header(frame: Frame, rows: int, cols: int, *, fix_crc: bool) -> bytes:
    """The frame's body with ``rows``/``cols`` replaced: as corrupted in transit (the CRC of
    the original body), or as a buggy sender writes it (a CRC over the wrong header)."""
    raw = np.asarray(frame.raw, dtype="<u2")
    header = HEADER.pack(1, 0, frame.sensor_id, frame.seq, frame.device_time_us,
                         raw.shape[0], raw.shape[1])
    body = header + raw.tobytes()
    crc = zlib.crc32(body)
    bad = bytearray(body)
    bad[16], bad[17] = rows, cols
    if fix_crc:
        crc = zlib.crc32(bytes(bad))
    return cobs_encode(bytes(bad) + crc.to_bytes(4, "little")) + b"\x00"


def build_wire(frames: list[Frame], fault: str, seed: int) -> Wire:
    """Encode ``frames`` with ``fault`` injected (``garbage``, ``bitflip``, ``truncated``,
    ``length`` or ``mixed``); frames before the zeroer has settled are left clean."""
    rng = random.Random(seed)
    wire = Wire()
    for i, frame in enumerate(frames):
        encoded = encode_frame(frame)
        kinds = ["garbage", "truncated", "length"] if fault == "mixed" else [fault]
        kind = rng.choice(kinds)
        if i < 40 or rng.random() > 0.1:  # ~10 % of frames get a fault
            kind = "none"
        if kind == "garbage":
            if wire.faults.get("oversize_garbage", 0) == 0 and i > 200:
                wire.data += bytes(rng.randrange(1, 256) for _ in range(MAX_ENCODED_LEN + 500))
                wire.count("oversize_garbage")  # no 0x00 at all: dropped unread up to one
            else:
                wire.data += _garbage(rng)
                wire.count("garbage_bursts")
            wire.add(encoded)
        elif kind == "truncated":
            cut = rng.randrange(1, len(encoded) - 1)
            reset = rng.random() < 0.7  # the device reset and sent its start-up 0x00
            wire.add(encoded[:cut] + (b"\x00" if reset else b""), damaged=True)
            wire.count("truncated_then_reset" if reset else "truncated_glued")
        elif kind == "length" and rng.random() < 0.15:
            # A sender bug the CRC cannot see: a well-formed 4x16 frame of the same 64 counts.
            # The decoder must deliver it (it is valid on the wire); the pipeline must drop it
            # (bad_shape) instead of treating it as this sensor's 8x8 frame.
            odd = Frame(seq=frame.seq, device_time_us=frame.device_time_us,
                        raw=frame.raw.reshape(4, 16), sensor_id=frame.sensor_id)
            wire.reshaped[len(wire.spans)] = odd
            wire.add(encode_frame(odd))
            wire.count("well_formed_4x16")
        elif kind == "length":
            rows, cols = frame.raw.shape
            r2, c2 = rows, cols
            while (r2, c2) == (rows, cols):
                r2, c2 = rng.choice([(rows, cols + 1), (rows + 1, cols), (rows - 1, cols),
                                     (0, cols), (rows, 255), (255, 255), (4, 16),
                                     (rng.randrange(1, 256), rng.randrange(1, 256))])
            # A sender bug with a CRC over the wrong header is refused only if rows*cols no
            # longer matches the body (a 4x16 header on 64 counts would be a valid frame).
            sender_bug = r2 * c2 != rows * cols and rng.random() < 0.3
            wire.add(_with_header(frame, r2, c2, fix_crc=sender_bug), damaged=True)
            wire.count("length_sender_bug" if sender_bug else "length_in_transit")
        else:
            wire.add(encoded)
    if fault in ("bitflip", "mixed"):
        wire.flip_bits(rng, BIT_ERROR_RATE)
    if wire.data[-1] != 0:
        wire.data += b"\x00"
    return wire


# --------------------------------------------------------------------------------------------
# Through the daemon


def _daemon(url: str, lossless: bool) -> tuple[Daemon, TapDecoder]:
    tap = TapDecoder()
    settings = load_settings(None, {}, {"sensor[0].name": SENSOR, "sensor[0].url": url,
                                        "sensor[0].wire_id": WIRE_ID})
    return Daemon(settings, lossless=lossless,
                  sources={SENSOR: open_source(url, decoder=tap)}), tap


async def _play(pty_device, frames: list[Frame], wire: Wire, lossless: bool,
                chunk: int = 509) -> dict:
    daemon, tap = _daemon(serial_url(pty_device.path), lossless)
    estimates = collect(daemon)
    zeroed = collect(daemon, "frame")
    await daemon.start()
    try:
        await wait_open(daemon, SENSOR)
        # The bytes go out as fast as the pty takes them, far faster than the device's
        # 500 Hz: the whole 2 s contact can be read in less time than its first fit takes (a
        # worker's first fit of a contact, 30-200 ms here), and in live mode a fit whose
        # contact has ended answers nothing.  A device sending at its own rate gives the fits
        # time; here the stream stops in the middle of the hold until a fit of the contact is
        # out, then goes on.
        hold = wire.spans[len(frames) // 2][1]
        await pty_device.send(bytes(wire.data[:hold]), chunk=chunk)
        await wait_for(lambda: any(e.gate == "fit" and e.contact for e in estimates), 30,
                       "a fit of the held contact published")
        await pty_device.send(bytes(wire.data[hold:]), chunk=chunk)
        pipe = daemon.sensors[SENSOR]
        await wait_for(lambda: tap.stats.bytes == len(wire.data) and pipe.settled, 30,
                       "all bytes decoded and every fit done")
        st = daemon.stats(SENSOR)
    finally:
        await daemon.stop()
    return {"tap": tap, "stats": st, "estimates": estimates, "zeroed": zeroed}


@pytest.mark.parametrize("fault,lossless", [
    ("garbage", False), ("bitflip", False), ("truncated", False), ("length", False),
    ("mixed", False), ("mixed", True),
], ids=["garbage", "bitflip", "truncated", "length", "mixed", "mixed-lossless"])
def test_damaged_stream(pty_device, arun, fault: str, lossless: bool) -> None:
    # The whole press scene: rest, press, hold (the middle of the stream), release (fits
    # outstanding as contact ends), rest.
    frames = scene_frames(1500, scene="press", rate_hz=500, seed=3, sensor_id=WIRE_ID)
    wire = build_wire(frames, fault, seed=SEEDS[fault])
    intact = wire.intact()
    r = arun(_play(pty_device, frames, wire, lossless))
    tap, st, estimates = r["tap"], r["stats"], r["estimates"]
    d = tap.stats

    # Every intact frame decoded, exactly as sent and in order; nothing else.
    assert tap.delivered == [fingerprint(wire.reshaped.get(i, frames[i])) for i in intact]
    good = [i for i in intact if i not in wire.reshaped]  # the sensor's own 8x8 frames
    # Every fault counted: each non-empty chunk between delimiters is a frame or a rejection.
    assert d.frames == len(intact)
    assert d.rejected == wire.chunks() - len(intact)
    assert d.duplicated == 0 and d.restarts == 0
    first, last = frames[intact[0]].seq, frames[intact[-1]].seq
    assert d.lost == (last - first + 1) - len(intact)
    # Back in sync within one frame: the first intact frame after any rejection is the next
    # good frame delivered (the sequence above), and counted as a resync.
    assert d.resyncs == wire.expected_resyncs(set(intact))
    if fault == "truncated":
        assert d.truncated >= wire.faults.get("truncated_then_reset", 0)
        assert d.rejected == d.truncated + d.crc_errors + d.cobs_errors
    if fault == "length":
        assert d.length_errors == wire.faults.get("length_sender_bug", 0)
    if fault == "garbage":
        assert d.oversize == 1
        lost_frames = len(frames) - len(intact)
        assert lost_frames <= wire.faults["garbage_bursts"] + 1  # at most one frame per burst

    # No corrupt frame accepted: everything published is a frame sent intact.
    sent = {(frames[i].seq, frames[i].device_time_us) for i in good}
    corrupt = [e for e in estimates + r["zeroed"] if (e.seq, e.device_time_us) not in sent]
    assert not corrupt, f"published items of frames not sent intact: {corrupt[:3]}"
    assert len(r["zeroed"]) == len(good)
    assert st["bad_shape"] == len(intact) - len(good)
    check_estimates(estimates)  # strict JSON, seq strictly increasing, gates consistent
    # ... and every intact frame accounted for by the pipeline.
    assert st["frames"] == len(intact) == accounted(st)
    assert st["decoder"]["crc_errors"] == d.crc_errors  # the health view shows the same counts
    if lossless:
        assert [e.seq for e in estimates] == [frames[i].seq for i in good]
        assert st["superseded"] == 0
    assert any(e.gate == "fit" and e.contact for e in estimates)
    assert st["wrong_sensor"] == st["errors"] == st["fit_errors"] == 0
    figures(f"damaged_stream[{fault}{'-lossless' if lossless else ''}]",
            frames_sent=len(frames), faults=wire.faults, intact=len(intact),
            decoded=d.frames, rejected=d.rejected, crc=d.crc_errors, cobs=d.cobs_errors,
            truncated=d.truncated, length=d.length_errors, oversize=d.oversize, lost=d.lost,
            resyncs=d.resyncs, estimates=len(estimates), superseded=st["superseded"],
            stale_dropped=st["stale_dropped"], bad_shape=st["bad_shape"],
            corrupt_accepted=len(corrupt))


async def _split_every_point(pty_device, frames: list[Frame], byte_at_a_time: Frame) -> dict:
    daemon, tap = _daemon(serial_url(pty_device.path), lossless=False)
    estimates = collect(daemon)
    await daemon.start()
    try:
        await wait_open(daemon, SENSOR)
        await pty_device.send(b"\x00")
        await wait_for(lambda: tap.stats.bytes == 1, 10, "start-up delimiter read")
        fed = 1
        for k, frame in enumerate(frames, start=1):  # frame k split after its k-th byte
            encoded = encode_frame(frame)
            await pty_device.send(encoded[:k])
            await wait_for(lambda: tap.buffered == k, 10, f"first {k} bytes read")
            await pty_device.send(encoded[k:])
            fed += len(encoded)
            await wait_for(lambda: tap.stats.bytes == fed, 10, "rest read")
        encoded = encode_frame(byte_at_a_time)
        for j in range(len(encoded)):  # one read per byte
            await pty_device.send(encoded[j:j + 1])
            fed += 1
            await wait_for(lambda: tap.stats.bytes == fed, 10, f"byte {j} read")
        pipe = daemon.sensors[SENSOR]
        await wait_for(lambda: pipe.settled, 10, "fits done")
        st = daemon.stats(SENSOR)
    finally:
        await daemon.stop()
    return {"tap": tap, "stats": st, "estimates": estimates}


def test_every_split_point_across_reads(pty_device, arun) -> None:
    """Frame k is written in two pieces, the first k bytes and the rest; the test waits until
    the decoder holds exactly k bytes before writing the rest, so the split is a real split
    between two reads of the port.  Then one frame arrives a byte per read."""
    length = len(encode_frame(scene_frames(1, sensor_id=WIRE_ID)[0]))
    frames = scene_frames(length, scene="press", rate_hz=100, seed=5, sensor_id=WIRE_ID)
    # Every frame of this stream has the same encoded length, so every split point is covered.
    assert {len(encode_frame(f)) for f in frames[:-1]} == {length}
    split, last = frames[:-1], frames[-1]
    r = arun(_split_every_point(pty_device, split, last))
    tap, st = r["tap"], r["stats"]
    assert tap.delivered == [fingerprint(f) for f in frames]
    assert tap.stats.rejected == 0 and tap.stats.lost == 0
    assert st["frames"] == len(frames) == accounted(st)
    check_estimates(r["estimates"])
    figures("every_split_point", split_points=len(split), frame_bytes=length,
            byte_reads=length, delivered=tap.stats.frames, rejected=tap.stats.rejected)
