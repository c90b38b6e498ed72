"""Re-simulating a damaged recording (``belt-drive sim REC.mcap``) is refused in one line naming the file.

A fresh-clone run once printed ``'utf-8' codec can't decode byte 0xae ...`` for a
recording cut at 60 % of its bytes: the mcap library's reader parsed the cut
file's bytes as a record and its error reached the user without the file's
name; other cuts gave ``[Errno 22] Invalid argument`` (a seek before the
start) and exit 1, as a failed write. Which error a cut gives depends on where
it lands, so these tests cut a small recording at every record boundary (and
the bytes around it), every byte of its end and at a stride between, and flip
single bytes the same way.

* A cut file is refused before its scene is rebuilt: ``<file>: cannot
  re-simulate a damaged or incomplete recording (<what msg-tools found>)``.
* A flipped byte is refused the same way, or, where it lands in a copy the
  reader does not use (the data section's schema and channel records, the
  message indexes), changes nothing: the same scene and the same pass-through
  messages as the intact file. Never a silently different result.
"""

from __future__ import annotations

import errno
import struct
import warnings

import pytest

from belt_drive_ros.cli import main
from belt_drive_ros.io.recording import BagReadError
from belt_drive_ros.io.resimulate import resimulation

MAGIC = 8  # bytes of the MCAP magic at either end
FOOTER = 0x02


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A 10 ms ``paper`` recording (~29 kB: header, schemas, channels, one chunk, metadata, summary)."""
    folder = tmp_path_factory.mktemp("recording")
    rec = folder / "rec.mcap"
    assert main(["sim", "paper", "--duration", "0.01", "--quiet", "--out", str(rec)]) == 0
    return rec.read_bytes()


def _records(data: bytes):
    """Start offsets of the file's top-level records, the footer included."""
    starts, pos = [], MAGIC
    while pos + 9 <= len(data):
        starts.append(pos)
        opcode, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if opcode == FOOTER:
            break
        pos += 9 + length
    return starts


def _offsets(data: bytes, stride: int):
    """Record boundaries and their header bytes, the file's last 128 bytes, and a stride."""
    offsets = {s + d for s in _records(data) for d in (-1, 0, 1, 5, 9)}
    offsets |= set(range(len(data) - 128, len(data)))
    offsets |= set(range(MAGIC, len(data), stride))
    return sorted(o for o in offsets if 0 < o < len(data))


def _resimulate(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return resimulation(path)


def _refusal(exc: BagReadError, path) -> str:
    message = str(exc)
    assert "\n" not in message and message.startswith(f"{path}: "), message
    return message


def _flipped(recording: bytes, offset: int, path):
    """The re-simulation of ``recording`` with the byte at ``offset`` flipped, written to ``path``; None where it is
    refused (in one line naming the file)."""
    flipped = bytearray(recording)
    flipped[offset] ^= 0xFF
    path.write_bytes(bytes(flipped))
    try:
        return _resimulate(path)
    except BagReadError as exc:
        _refusal(exc, path)
        return None


def test_the_intact_recording_re_simulates(recording, tmp_path):
    path = tmp_path / "rec.mcap"
    path.write_bytes(recording)
    resim = _resimulate(path)
    assert resim.passthrough and len(_records(recording)) > 20


def test_every_cut_of_a_recording_is_refused_naming_the_file(recording, tmp_path):
    path = tmp_path / "cut.mcap"
    offsets = _offsets(recording, 101)
    assert len(offsets) > 400
    for offset in offsets:
        path.write_bytes(recording[:offset])
        with pytest.raises(BagReadError) as info:
            _resimulate(path)
        message = _refusal(info.value, path)
        assert "cannot re-simulate a damaged or incomplete recording" in message, (offset, message)


def test_a_flipped_byte_is_refused_or_changes_nothing(recording, tmp_path):
    intact = tmp_path / "rec.mcap"
    intact.write_bytes(recording)
    reference = _resimulate(intact)
    path = tmp_path / "flipped.mcap"
    refused = same = 0
    for offset in _offsets(recording, 157):
        if offset >= len(recording) - MAGIC:
            continue  # the closing magic: msg-tools' own tests cover a file that does not end as MCAP
        resim = _flipped(recording, offset, path)
        if resim is None:
            refused += 1
            continue
        assert resim.passthrough == reference.passthrough, offset
        assert resim.scene == reference.scene, offset
        assert (resim.start_time_ns, resim.output_rate) == (reference.start_time_ns, reference.output_rate), offset
        same += 1
    assert refused > 150 and same > 0, (refused, same)


@pytest.mark.parametrize("where", ["cut at 60%", "a byte flipped in the summary's first channel"])
def test_the_sim_command_refuses_a_damaged_recording_in_one_line(recording, tmp_path, capsys, where):
    path = tmp_path / "bad.mcap"
    if where.startswith("cut"):
        path.write_bytes(recording[: int(len(recording) * 0.6)])
    else:
        data_end = next(s for s in _records(recording) if recording[s] == 0x0F)
        channel = next(s for s in _records(recording) if s > data_end and recording[s] == 0x04)
        flipped = bytearray(recording)
        flipped[channel + 9 + 4] ^= 0xFF  # inside the channel's topic
        path.write_bytes(bytes(flipped))
    capsys.readouterr()
    assert main(["sim", str(path), "--quiet", "--out", str(tmp_path / "re.mcap")]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and str(path) in err[0] and "damaged or incomplete" in err[0], err
    assert not (tmp_path / "re.mcap").exists()


def test_a_failed_disk_read_is_a_read_error_naming_the_file(recording, tmp_path, monkeypatch):
    """An I/O error while the messages are read (the disk, not the file's bytes) was reported as a failed write
    (``BagWriteError``, the message without the file's name): it is a read error naming the file."""
    import belt_drive_ros.io.resimulate as resimulate

    path = tmp_path / "rec.mcap"
    path.write_bytes(recording)

    def failing(file, topics=None):
        raise OSError(errno.EIO, "Input/output error")
        yield  # (a generator, as the reader is)

    monkeypatch.setattr(resimulate, "_messages_of_whole", failing)
    with pytest.raises(BagReadError) as info:
        _resimulate(path)
    assert "Input/output error" in _refusal(info.value, path)


def test_a_flipped_byte_in_a_message_index_leaves_the_start_time(recording, tmp_path):
    """Every byte of the data section's message index records (no CRC covers them) flipped in turn: the
    re-simulation starts where the intact file does. A topic's first time is read off those indexes, and one of
    them flipped re-simulated the run from 1039 ns since the epoch, or 8 us early."""
    intact = tmp_path / "rec.mcap"
    intact.write_bytes(recording)
    reference = _resimulate(intact)
    starts = _records(recording)
    indexes = [a for a in starts if recording[a] == 0x07]  # MessageIndex records
    assert indexes
    path = tmp_path / "flipped.mcap"
    checked = 0
    for a in indexes:
        length = struct.unpack_from("<Q", recording, a + 1)[0]
        for offset in range(a + 9, a + 9 + length):
            resim = _flipped(recording, offset, path)
            if resim is None:
                continue
            assert resim.start_time_ns == reference.start_time_ns, offset
            checked += 1
    assert checked > 100
