"""A full disk, an unwritable output and a damaged store: one line, nothing half-written left
behind, every earlier file intact. The full disk is injected (ENOSPC raised by a write, or the
folder's free space reported as none): this machine cannot mount a small filesystem."""
import errno
import json
import shutil
import time
from collections import namedtuple

import numpy as np
import pytest

import wmthesis.runs as runs
from wmthesis.runs import DiskFull, atomic_path, check_writable, write_json

Usage = namedtuple("Usage", "total used free")


def no_space(monkeypatch):
    """Every folder reports no free space from now on (where the runs module asks)."""
    monkeypatch.setattr(runs.shutil, "disk_usage", lambda folder: Usage(1 << 30, 1 << 30, 0))


def test_a_write_that_fails_on_a_full_disk_names_the_folder_and_leaves_the_earlier_file(tmp_path, monkeypatch):
    path = write_json(tmp_path / "metrics.json", {"score": 1})
    with pytest.raises(DiskFull, match=f"no space left on {tmp_path}: metrics.json was not written") as raised:
        with atomic_path(path) as tmp:
            tmp.write_text('{"score": ')
            raise OSError(errno.ENOSPC, "No space left on device")
    assert raised.value.errno == errno.ENOSPC
    assert json.loads(path.read_text()) == {"score": 1} and [p.name for p in tmp_path.iterdir()] == ["metrics.json"]

    import torch  # torch hides ENOSPC behind "basic_ios::clear: iostream error": the free space tells

    no_space(monkeypatch)
    with pytest.raises(DiskFull, match="weights.pt was not written"):
        with atomic_path(tmp_path / "weights.pt") as tmp:
            torch.save({"w": torch.zeros(3)}, tmp)
            raise RuntimeError("basic_ios::clear: iostream error")
    assert [p.name for p in tmp_path.iterdir()] == ["metrics.json"]
    with pytest.raises(ValueError, match="not a full disk"):  # other errors stay what they are
        monkeypatch.setattr(runs.shutil, "disk_usage", lambda folder: Usage(1 << 30, 0, 1 << 30))
        with atomic_path(tmp_path / "x.json"):
            raise ValueError("not a full disk")


def test_collect_onto_a_full_disk_is_one_line_exit_1_and_keeps_the_episodes_before(tmp_path, monkeypatch, capsys):
    from wmthesis.__main__ import main
    from wmthesis.data import EpisodeStore

    out = tmp_path / "store.h5"
    assert main(["collect", "sokoban-small", "--episodes", "2", "--workers", "1", "--out", str(out),
                 "--profile", "smoke"]) == 0
    capsys.readouterr()
    no_space(monkeypatch)
    assert main(["collect", "sokoban-small", "--episodes", "4", "--workers", "1", "--out", str(out),
                 "--profile", "smoke"]) == 1
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip() and "collect sokoban-small" not in line]  # the bar aside
    assert len(lines) == 1 and f"no space left on {tmp_path}: episode 2 of store.h5" in lines[0], err
    assert "MiB are free" in err and "Traceback" not in err
    with EpisodeStore(out) as store:
        assert len(store) == 2  # the earlier episodes, whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["store.h5"]


def test_a_recording_onto_a_full_disk_stops_and_leaves_no_half_file(tmp_path, monkeypatch):
    from wmthesis.thoughts import SPACE_CHECK_STEPS, Recorder

    recorder = Recorder(tmp_path / "bout.rrd", horizon=2, video=tmp_path / "bout.mp4")
    frame = np.zeros((16, 16, 3), np.uint8)
    for _ in range(SPACE_CHECK_STEPS):
        recorder.step(frame)
        recorder.outcome(0.0)
    no_space(monkeypatch)
    with pytest.raises(DiskFull, match=f"no space left on {tmp_path}: bout.rrd was not written"):
        recorder.step(frame)
    assert recorder.close()["errors"] == {} and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name, says", [
    ("folder", "is a folder: name a file in it"),
    ("missing/x.json", "its folder {tmp}/missing does not exist"),
    ("x.txt", "name a .json file"),
])
def test_an_output_that_cannot_be_written_is_refused_naming_the_users_path(tmp_path, name, says):
    (tmp_path / "folder").mkdir()
    with pytest.raises(ValueError, match=says.format(tmp=tmp_path)):
        check_writable(tmp_path / name, ".json")


def test_an_output_in_a_folder_that_takes_no_file_is_refused_before_any_level_is_played(tmp_path, capsys):
    from wmthesis.__main__ import main

    with pytest.raises(ValueError, match="/proc/x.json cannot be written: its folder /proc takes no new file"):
        check_writable("/proc/x.json")  # writable to os.access as root, yet no file can be made there
    levels = tmp_path / "levels.txt"
    levels.write_text("#####\n#@$.#\n#####\n")
    started = time.perf_counter()
    assert main(["solve-sokoban", str(levels), "--out", "/proc/x.json", "--profile", "smoke"]) == 2
    err = capsys.readouterr().err
    assert "/proc/x.json cannot be written" in err and ".tmp" not in err and err.count("\n") == 1
    assert time.perf_counter() - started < 5  # before the agent loads or a level plays
    assert main(["collect", "sokoban-small", "--episodes", "1", "--out", str(tmp_path), "--profile", "smoke"]) == 2
    assert "is a folder" in capsys.readouterr().err


def test_the_store_refuses_nan_rewards_and_names_itself_when_a_chunk_is_damaged(tmp_path):
    from wmthesis.data import EpisodeStore, StoreError
    from wmthesis.rollouts import collect

    path = collect("sokoban-small", 2, tmp_path / "s.h5", progress=False)
    with EpisodeStore(path, "a") as store:
        steps = len(store.episode(0)["actions"])
        episode = store.episode(0)
        rewards = episode["rewards"].copy()
        rewards[1] = np.nan
        with pytest.raises(ValueError, match=r"rewards hold NaN or infinity \(step 1 of"):
            store.append_episode(episode["observations"], episode["actions"], rewards, episode["terminals"])
        assert len(store) == 2
    data = bytearray(path.read_bytes())
    with EpisodeStore(path) as store:  # the first observation chunk's bytes, found in the file
        offset = store._data["observations"].id.get_chunk_info(0).byte_offset
    data[offset + 16:offset + 400] = bytes(384)
    damaged = tmp_path / "damaged.h5"
    damaged.write_bytes(bytes(data))
    with EpisodeStore(damaged) as store:
        assert steps > 0
        with pytest.raises(StoreError, match=r"damaged\.h5: cannot read episode 0 .*delete it and collect again"):
            store.episode(0)


def test_the_models_refuse_nan_at_their_door():
    import torch

    from wmthesis.world_models.controller import Controller
    from wmthesis.world_models.vision import VAE, VAEVision

    controller = Controller(4, 3, 5)
    with pytest.raises(ValueError, match=r"latents z hold NaN or infinity \(1 of 4 values\)"):
        controller.act(torch.tensor([[0.0, float("nan"), 0.0, 0.0]]), torch.zeros(1, 3))
    with pytest.raises(ValueError, match="memory state h hold NaN"):
        controller(torch.zeros(1, 4), torch.full((1, 3), float("inf")))
    flat = controller.get_flat()
    flat[3] = np.nan
    with pytest.raises(ValueError, match="the controller's parameters hold NaN"):
        controller.set_flat(flat)
    assert controller.act(torch.zeros(2, 4), torch.zeros(2, 3)).shape == (2,)
    vision = VAEVision(VAE(8))
    with pytest.raises(ValueError, match="the latents to decode hold NaN"):
        vision.decode(np.full((1, 8), np.nan, np.float32))
    with pytest.raises(ValueError, match="uint8 frames"):
        vision(np.full((1, 64, 64, 3), np.nan, np.float32))


SHIPPED_DATA = str(__import__("pathlib").Path(__file__).resolve().parents[1] / "data")


def test_play_record_onto_a_full_disk_is_one_line_exit_1_and_leaves_no_half_file(tmp_path, monkeypatch, capsys):
    from wmthesis.__main__ import main

    monkeypatch.setenv("WMTHESIS_DATA", SHIPPED_DATA)  # the shipped agent
    no_space(monkeypatch)
    assert main(["play", "boxing-wm", "--profile", "quick", "--bouts", "1", "--record", str(tmp_path / "bout.rrd"),
                 "--video", str(tmp_path / "bout.mp4")]) == 1
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1].startswith(f"error: no space left on {tmp_path}: bout.rrd was not written"), err
    assert "Traceback" not in err and list(tmp_path.iterdir()) == []


def test_solve_sokoban_out_onto_a_full_disk_is_one_line_exit_1_and_leaves_no_half_file(tmp_path, monkeypatch, capsys):
    import os

    from wmthesis.__main__ import main

    monkeypatch.setenv("WMTHESIS_DATA", SHIPPED_DATA)
    levels, out = tmp_path / "levels.txt", tmp_path / "out" / "solved.json"
    levels.write_text("#####\n#@$.#\n#####\n")
    out.parent.mkdir()
    replace = os.replace

    def full(source, target):  # the disk fills as the answers are moved into place
        if str(target) == str(out):
            raise OSError(errno.ENOSPC, "No space left on device")
        return replace(source, target)

    monkeypatch.setattr(runs.os, "replace", full)
    assert main(["solve-sokoban", str(levels), "--profile", "quick", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("levels:")]  # the bar aside
    assert lines == [f"error: no space left on {out.parent}: solved.json was not written; free some space and run it "
                     "again"], err
    assert list(out.parent.iterdir()) == []


def test_outputs_that_take_no_file_are_refused_before_anything_heavy_loads(tmp_path):
    """``/proc`` takes no new file though it looks writable to root; a folder is no file: each
    output refused in one line naming the user's path, before torch, ale-py or the agent load."""
    import subprocess
    import sys

    (tmp_path / "folder.mp4").mkdir()
    cases = [(["play", "boxing-wm", "--record", "/proc/x.rrd"], "/proc/x.rrd cannot be written"),
             (["play", "boxing-wm", "--video", "/proc/x.mp4"], "/proc/x.mp4 cannot be written"),
             (["play", "boxing-wm", "--video", str(tmp_path / "folder.mp4")], f"{tmp_path}/folder.mp4 is a folder"),
             (["collect", "boxing", "--out", "/proc/x.h5"], "/proc/x.h5 cannot be written")]
    code = ("import sys, contextlib, io\nfrom wmthesis.__main__ import main\n"
            f"for argv, _ in {cases!r}:\n"
            "    err = io.StringIO()\n"
            "    with contextlib.redirect_stderr(err):\n"
            "        code = main(argv)\n"
            "    heavy = sorted(m for m in ('torch', 'ray', 'ale_py') if m in sys.modules)\n"
            "    print(repr((code, err.getvalue(), heavy)))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    for (argv, says), line in zip(cases, done.stdout.splitlines()):
        status, err, heavy = eval(line)
        assert status == 2 and says in err and err.count("\n") == 1 and ".tmp" not in err and heavy == [], (argv, line)


def test_reproduce_onto_a_full_disk_is_one_line_exit_1_and_leaves_no_half_file(tmp_path, monkeypatch, capsys):
    from wmthesis.__main__ import main

    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    no_space(monkeypatch)
    assert main(["reproduce", "sokoban-wm", "--profile", "smoke"]) == 1
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and lines[0].startswith("error: no space left on ") and "Traceback" not in err, err
    assert not [p for p in tmp_path.rglob("*") if ".tmp" in p.name or p.suffix in (".pt", ".json")]


def test_ctrl_c_during_collect_is_one_line_exit_130_and_keeps_the_episodes_before(tmp_path):
    """A real SIGINT, as a terminal sends it, to a command collecting episodes."""
    import os
    import signal
    import subprocess
    import sys

    from wmthesis.data import EpisodeStore

    out = tmp_path / "store.h5"
    command = subprocess.Popen([sys.executable, "-m", "wmthesis", "collect", "sokoban-small", "--episodes", "100000",
                                "--workers", "1", "--out", str(out), "--profile", "smoke"],
                               stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.default_int_handler))
    deadline = time.time() + 60
    while time.time() < deadline and not (out.is_file() and out.stat().st_size > 4096):
        time.sleep(0.5)
    time.sleep(2)  # some episodes in
    command.send_signal(signal.SIGINT)
    _, err = command.communicate(timeout=60)
    lines = [line for line in err.splitlines() if line.strip() and "collect sokoban-small" not in line]  # the bar aside
    with EpisodeStore(out) as store:
        kept = len(store)  # the episodes before, whole
    assert command.returncode == 130 and kept > 0 and lines == [
        f"collect interrupted: {out} keeps {kept} complete episodes; run the same command again to resume"], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["store.h5"]


# ------------------------------------------------------------- a real small filesystem, where mounting is allowed
@pytest.fixture
def mounted(tmp_path):
    """``mount(kind)``: a 2 MiB tmpfs (``"small"``) or a read-only bind mount (``"read-only"``) in
    ``tmp_path``, unmounted after the test; the test is skipped where this machine allows no mount."""
    import subprocess

    mounts = []

    def mount(kind: str):
        target = tmp_path / kind
        target.mkdir()
        if kind == "small":
            steps = [["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(target)]]
        else:
            steps = [["mount", "--bind", str(tmp_path), str(target)], ["mount", "-o", "remount,bind,ro", str(target)]]
        for step in steps:
            done = subprocess.run(step, capture_output=True, text=True)
            if done.returncode != 0:
                pytest.skip(f"this machine allows no {kind} mount: {done.stderr.strip()}")
            if step[1] in ("-t", "--bind"):
                mounts.append(target)
        return target

    yield mount
    for target in reversed(mounts):
        subprocess.run(["umount", "-l", str(target)], capture_output=True)


def test_collect_onto_a_small_filesystem_is_one_line_exit_1_and_keeps_the_episodes_before(mounted, capsys):
    from wmthesis.__main__ import main
    from wmthesis.data import EpisodeStore

    disk = mounted("small")
    out = disk / "store.h5"
    assert main(["collect", "boxing", "--episodes", "200", "--workers", "1", "--out", str(out),
                 "--profile", "smoke"]) == 1
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip() and "collect boxing" not in line]  # the bar aside
    assert len(lines) == 1 and lines[0].startswith(f"error: no space left on {disk}: "), err
    with EpisodeStore(out) as store:
        assert 0 < len(store) < 200 and store.episode(len(store) - 1)["actions"].size > 0  # whole episodes
    assert [p.name for p in disk.iterdir()] == ["store.h5"]


def test_solve_sokoban_out_onto_a_filesystem_that_fills_leaves_no_half_file(mounted, monkeypatch, capsys):
    from wmthesis.__main__ import main

    monkeypatch.setenv("WMTHESIS_DATA", SHIPPED_DATA)
    disk = mounted("small")
    (disk / "filler").write_bytes(bytes(2 * 1024 * 1024 - 2048))  # a few KiB left
    levels = disk.parent / "levels.txt"
    levels.write_text("\n\n".join(f"; {k}\n#####\n#@$.#\n#####" for k in range(40)))
    assert main(["solve-sokoban", str(levels), "--profile", "quick", "--out", str(disk / "solved.json")]) == 1
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(err) == 1 and err[0].startswith(f"error: no space left on {disk}: {disk}/solved.json, the solutions of "
                                               "40 levels, needs about")  # refused before a level is played
    assert [p.name for p in disk.iterdir()] == ["filler"]


def test_an_output_on_a_read_only_mount_is_refused_before_anything_plays(mounted, capsys):
    from wmthesis.__main__ import main

    read_only = mounted("read-only")
    with pytest.raises(ValueError, match=f"{read_only}/x.json cannot be written"):
        check_writable(read_only / "x.json", ".json")
    started = time.perf_counter()
    assert main(["play", "boxing-wm", "--record", str(read_only / "bout.rrd")]) == 2
    err = capsys.readouterr().err
    assert f"{read_only}/bout.rrd cannot be written" in err and err.count("\n") == 1
    assert time.perf_counter() - started < 5
