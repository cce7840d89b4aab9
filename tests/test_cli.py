import subprocess
import sys


def test_seesys_help_lists_part_groups():
    out = subprocess.run([sys.executable, "-m", "seesys", "--help"], capture_output=True, text=True, check=True)
    assert "usage: seesys" in out.stdout
