"""The recording file format: header, records, truncation, appending, the Recorder."""

from __future__ import annotations

import logging
import struct
import time

import pytest

from tactiled.errors import FrameError
from tactiled.frames import FrameDecoder, encode_frame
from tactiled.io.recording import (
    HEADER_SIZE,
    MAGIC,
    RECORD_HEADER_SIZE,
    Recorder,
    RecordingReader,
    RecordingWriter,
    read_recording,
)


def write_file(path, frames, period=0.01, t0=100.0, sensor_id=0):
    with RecordingWriter(path, sensor_id=sensor_id, created=1.7e9) as writer:
        for k, frame in enumerate(frames):
            writer.write(t0 + k * period, encode_frame(frame))
    return path


def test_layout_is_as_documented(tmp_path, frame_factory) -> None:
    frame = frame_factory(1)[0]
    path = write_file(tmp_path / "a.tact", [frame], t0=12.5, sensor_id=7)
    data = path.read_bytes()
    assert HEADER_SIZE == 32 and RECORD_HEADER_SIZE == 12
    assert data[:8] == MAGIC == b"TACTREC\x00"
    assert struct.unpack_from("<HHIdQ", data, 8) == (1, 32, 7, 1.7e9, 0)
    wire = encode_frame(frame)
    assert struct.unpack_from("<dI", data, 32) == (12.5, len(wire))
    assert data[44:] == wire and len(data) == 32 + 12 + len(wire)


def test_round_trip(tmp_path, frame_factory, same_frame) -> None:
    sent = frame_factory(10)
    path = write_file(tmp_path / "a.tact", sent, sensor_id=3)
    with RecordingReader(path) as reader:
        assert (reader.header.version, reader.header.sensor_id) == (1, 3)
        assert reader.header.created == 1.7e9
        records = list(reader)
        assert reader.records == 10 and not reader.truncated
        assert list(reader) == records  # iterating again starts over
    assert [t for t, _ in records] == [100.0 + k * 0.01 for k in range(10)]
    decoder = FrameDecoder()
    got = decoder.feed(b"".join(data for _, data in records))
    assert all(same_frame(a, b) for a, b in zip(got, sent, strict=True))


@pytest.mark.parametrize("cut", [1, RECORD_HEADER_SIZE - 1, RECORD_HEADER_SIZE,
                                 RECORD_HEADER_SIZE + 1, RECORD_HEADER_SIZE + 100])
def test_truncated_last_record_reported_not_raised(tmp_path, frame_factory, caplog,
                                                   cut) -> None:
    path = write_file(tmp_path / "a.tact", frame_factory(5))
    size = path.stat().st_size
    record = RECORD_HEADER_SIZE + len(encode_frame(frame_factory(1)[0]))
    complete_end = size - record
    with open(path, "r+b") as f:
        f.truncate(complete_end + cut)
    with caplog.at_level(logging.WARNING, logger="tactiled.io.recording"), \
            RecordingReader(path) as reader:
        records = list(reader)
    assert len(records) == 4
    assert reader.truncated and reader.truncated_bytes == cut
    assert reader.truncated_offset == complete_end
    assert "truncated" in caplog.text and str(complete_end) in caplog.text
    assert len(read_recording(path)) == 4
    with RecordingReader(path) as reader:  # the same verdict without reading the payloads
        assert reader.scan() == 4
    assert (reader.truncated, reader.truncated_bytes) == (True, cut)
    assert reader.truncated_offset == complete_end


def test_not_a_recording(tmp_path) -> None:
    for name, content, message in [
        ("text.tact", b"hello, this is not a recording at all..", "bad magic"),
        ("short.tact", MAGIC[:5], "header truncated"),
        ("empty.tact", b"", "header truncated"),
        ("v9.tact", MAGIC + struct.pack("<HHIdQ", 9, 32, 0, 0.0, 0), "version 9"),
    ]:
        path = tmp_path / name
        path.write_bytes(content)
        with pytest.raises(FrameError, match=message):
            RecordingReader(path)


def test_corrupt_length_mid_file_raises(tmp_path, frame_factory) -> None:
    path = write_file(tmp_path / "a.tact", frame_factory(3))
    with open(path, "r+b") as f:
        f.seek(HEADER_SIZE + 8)
        f.write(struct.pack("<I", 0xFFFFFFF0))
    with pytest.raises(FrameError, match=f"corrupt record at byte {HEADER_SIZE}"):
        read_recording(path)
    with RecordingReader(path) as reader, \
            pytest.raises(FrameError, match=f"corrupt record at byte {HEADER_SIZE}"):
        reader.scan()


def test_writer_refuses_to_overwrite_and_checks_input(tmp_path) -> None:
    path = tmp_path / "a.tact"
    with RecordingWriter(path) as writer:
        with pytest.raises(ValueError, match="host_time"):
            writer.write(float("nan"), b"\x01\x00")
        with pytest.raises(ValueError, match="record must hold"):
            writer.write(1.0, b"")
    with pytest.raises(FileExistsError):
        RecordingWriter(path)
    with pytest.raises(ValueError, match="sensor_id"):
        RecordingWriter(tmp_path / "b.tact", sensor_id=-1)


def test_append_continues_and_repairs_a_truncated_tail(tmp_path, frame_factory,
                                                       same_frame) -> None:
    frames = frame_factory(6)
    path = write_file(tmp_path / "a.tact", frames[:3], sensor_id=2)
    with open(path, "r+b") as f:  # a crash mid-record
        f.truncate(path.stat().st_size - 5)
    with RecordingWriter(path, sensor_id=2, append=True) as writer:
        assert writer.header.created == 1.7e9  # the original header is kept
        for k, frame in enumerate(frames[3:]):
            writer.write(200.0 + k, encode_frame(frame))
    records = read_recording(path)
    got = FrameDecoder().feed(b"".join(data for _, data in records))
    assert [f.seq for f in got] == [0, 1, 3, 4, 5]
    assert all(same_frame(a, b) for a, b in zip(got, frames[:2] + frames[3:], strict=True))
    with pytest.raises(FrameError, match="sensor 2"):
        RecordingWriter(path, sensor_id=5, append=True)
    # Appending nothing to a broken file still repairs it.
    path2 = write_file(tmp_path / "b.tact", frames[:2])
    with open(path2, "r+b") as f:
        f.truncate(path2.stat().st_size - 5)
    RecordingWriter(path2, append=True).close()
    with RecordingReader(path2) as reader:
        assert len(list(reader)) == 1 and not reader.truncated
    # append=True on a new file simply creates it.
    with RecordingWriter(tmp_path / "new.tact", append=True) as writer:
        writer.write(1.0, encode_frame(frames[0]))
    assert len(read_recording(tmp_path / "new.tact")) == 1


def test_flush_makes_records_visible_before_close(tmp_path, frame_factory) -> None:
    path = tmp_path / "a.tact"
    writer = RecordingWriter(path)
    writer.write(1.0, encode_frame(frame_factory(1)[0]))
    writer.flush()
    assert len(read_recording(path)) == 1
    writer.close()
    writer.close()  # idempotent
    assert writer.closed


def test_recorder_encodes_frames(tmp_path, frame_factory, same_frame) -> None:
    frames = frame_factory(4, sensor_id=9)
    frames[0].host_time = 55.0
    path = tmp_path / "rec.tact"
    before = time.monotonic()
    with Recorder(path, sensor_id=9, flush_interval=0.0) as recorder:
        recorder.record(frames[0])  # its own host_time
        recorder.record(frames[1])  # never stamped: now
        recorder.record(frames[2], host_time=60.0)
        assert recorder.frames_written == 3 and recorder.path == path
        assert len(read_recording(path)) == 3  # flush_interval=0 flushes every record
    records = read_recording(path)
    assert records[0][0] == 55.0 and records[2][0] == 60.0
    assert before <= records[1][0] <= time.monotonic()
    assert [data for _, data in records] == [encode_frame(f) for f in frames[:3]]
    with RecordingReader(path) as reader:
        assert reader.header.sensor_id == 9
    with pytest.raises(ValueError, match="flush_interval"):
        Recorder(tmp_path / "x.tact", flush_interval=-1)


def test_the_header_names_the_device_the_frames_came_from(tmp_path, frame_factory) -> None:
    """Bytes 24..31: the vendor driver's kind, ASCII, NUL-padded; zeros (files written before
    the field, or the wire format's own counts) read as no device."""
    frames = frame_factory(3)
    path = tmp_path / "px.tact"
    with RecordingWriter(path, device="paxini", created=1.0) as writer:
        writer.write(1.0, encode_frame(frames[0]))
    assert path.read_bytes()[24:32] == b"paxini\0\0"
    with RecordingReader(path) as reader:
        assert reader.header.device == "paxini" and reader.header.version == 1
    # appending: the same device only
    with pytest.raises(FrameError, match="device paxini"):
        RecordingWriter(path, append=True, device="xela")
    with RecordingWriter(path, append=True, device="paxini") as writer:
        writer.write(2.0, encode_frame(frames[1]))
    assert len(read_recording(path)) == 2
    with pytest.raises(FrameError, match="device paxini"):
        RecordingWriter(path, append=True)
    # an older file: the reserved bytes are zero; it takes a device's frames, header kept
    old = write_file(tmp_path / "old.tact", frames)
    assert old.read_bytes()[24:32] == bytes(8)
    with RecordingReader(old) as reader:
        assert reader.header.device is None
    with RecordingWriter(old, append=True, device="paxini") as writer:
        writer.write(9.0, encode_frame(frames[2]))
    assert old.read_bytes()[24:32] == bytes(8) and len(read_recording(old)) == 4
    # bytes that name nothing are not a device
    data = bytearray(old.read_bytes())
    data[24:32] = b"\xff\x01junk\0\0"
    (tmp_path / "odd.tact").write_bytes(bytes(data))
    with RecordingReader(tmp_path / "odd.tact") as reader:
        assert reader.header.device is None
    for bad in ("", "flexitac9", "p\u00e9", "a b"):
        with pytest.raises(ValueError, match="device"):
            RecordingWriter(tmp_path / f"bad{len(bad)}.tact", device=bad)
