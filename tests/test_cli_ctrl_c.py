"""Ctrl-C in a command: one line, exit 130, and the empty output folders it made removed."""

from __future__ import annotations

from conftest import run_msarm


def test_ctrl_c_prints_a_line_and_removes_the_empty_out_folder(monkeypatch, capsys, tmp_path):
    """typer turns a KeyboardInterrupt into exit code 130 before msarm's main sees it: until
    2026-11-29 the command ended silently and left the ``--out`` it had made behind, empty
    (a SIGTERM removed it and said ``msarm: terminated``)."""
    import msarm.tasks.track

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(msarm.tasks.track, "track", interrupted)
    out = tmp_path / "new" / "deep"
    code, _, err = run_msarm(monkeypatch, capsys, "track", "--task", "table1-1", "--out", str(out))
    assert code == 130
    assert err.strip().splitlines()[-1] == "msarm: interrupted"
    assert not (tmp_path / "new").exists()
