"""``belt-drive demo``'s offline part runs through the sim command with every option it reads."""

from belt_drive_ros.cli import main


def test_demo_offline_part_writes_csv_and_plot(tmp_path):
    assert main(["demo", "--no-live", "--out-dir", str(tmp_path)]) == 0
    assert (tmp_path / "paper.csv").stat().st_size > 0
    assert (tmp_path / "paper.png").read_bytes()[:4] == b"\x89PNG"


def test_demo_says_what_each_pulley_of_the_fead_did(tmp_path, capsys):
    from belt_drive_ros.io.scenes import load_network

    assert main(["demo", "--no-live", "--no-offline", "--out-dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    lines = {line[:18].strip(): line for line in out.splitlines() if line.startswith("  ") and line.strip()}
    for p in load_network("fead_i4").pulleys:  # a line per pulley: its speed, torque, power, hub load, grip
        assert "rpm mean" in lines[p.name] and "hub load" in lines[p.name] and "capstan limit" in lines[p.name]
    assert "gives" in lines["crank"] and "takes" in lines["alternator"] and "no power" in lines["idler"]
    assert "tightest" in lines["spans"] and "swinging" in lines["tensioner arm"]
    assert (tmp_path / "fead_i4.mcap").stat().st_size > 0


def test_an_interrupted_demo_stops_with_the_shells_status_and_runs_nothing_after(tmp_path):
    """Ctrl-C (SIGINT) during the live run: its summary is printed, the offline parts do not run, and the exit
    status is 130 (128 + SIGINT), as for any command a signal ended (it was 0, after running the rest)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from belt_drive_ros.ros import environment as ros_env

    env = {**ros_env.child_environment(ros_env.process_domain_id(offset=77)), "MPLBACKEND": "Agg"}
    proc = subprocess.Popen([sys.executable, "-u", "-m", "belt_drive_ros.cli", "demo", "--duration", "60",
                             "--out-dir", str(tmp_path)], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip
    try:
        seen = ""
        deadline = time.monotonic() + 120
        while "== live:" not in seen and time.monotonic() < deadline:  # the spin has started
            line = proc.stdout.readline()
            if not line:
                break
            seen += line
        assert "== live:" in seen, seen + proc.stderr.read()
        time.sleep(0.5)
        os.kill(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, (proc.returncode, err[-2000:])
    assert "interrupted by SIGINT during the live run" in err
    assert "offline" not in out and not (tmp_path / "paper.csv").exists()
