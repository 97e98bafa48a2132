"""The tracks journal writes through a buffer (pipeline/journal.py): what a snapshot relies on
must be in the file when ``dup_fd`` returns, and a record still in the buffer is one the resume
cuts anyway (it is after the snapshot)."""

from __future__ import annotations

import os

from bnptrack.pipeline.journal import TracksJournal, read_journal


def test_dup_fd_hands_every_appended_record_to_the_file(tmp_path):
    path = tmp_path / "tracks.journal"
    journal = TracksJournal(path, keep=100)
    journal.start()
    for seq in range(5):
        journal.append(seq, f"payload {seq}".encode(), {"frame": seq + 1})
    assert read_journal(path) == []  # five small records: still in the buffer
    fd = journal.dup_fd()
    try:
        got = read_journal(path)  # the journal is still open: only the flush put them there
        assert [(r.seq, r.payload, r.meta) for r in got] == [
            (seq, f"payload {seq}".encode(), {"frame": seq + 1}) for seq in range(5)]
        assert os.fstat(fd).st_size == os.path.getsize(path)
    finally:
        os.close(fd)
        journal.close()


def test_a_resume_keeps_what_the_snapshot_covers_and_cuts_the_rest(tmp_path):
    path = tmp_path / "tracks.journal"
    journal = TracksJournal(path, keep=100)
    journal.start()
    for seq in range(6):
        journal.append(seq, b"x" * seq, {})
    journal.close()  # a clean close flushes the buffer
    again = TracksJournal(path, keep=100)
    kept = again.resume(through_seq=3)
    assert [seq for seq, _p, _m in kept] == [0, 1, 2, 3]
    again.close()
    assert [r.seq for r in read_journal(path)] == [0, 1, 2, 3]
