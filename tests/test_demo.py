"""``belt-drive demo``'s offline part runs through the sim command with every option it reads."""

from belt_drive_ros.cli import main


def test_demo_offline_part_writes_csv_and_plot(tmp_path):
    assert main(["demo", "--no-live", "--out-dir", str(tmp_path)]) == 0
    assert (tmp_path / "paper.csv").stat().st_size > 0
    assert (tmp_path / "paper.png").read_bytes()[:4] == b"\x89PNG"
