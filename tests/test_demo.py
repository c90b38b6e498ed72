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
