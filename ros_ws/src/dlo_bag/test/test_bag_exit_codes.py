"""One exit-status table for the bag tools (dlo_bag.bag EXIT_*), each case as a user meets it."""
import pytest

from dlo_bag import analysis, bag_info, recover
from dlo_bag.bag import EXIT_BAD_BAG, EXIT_USAGE

TOOLS = {"dlo-bag-info": bag_info.main, "dlo-analyze": analysis.main, "dlo-bag-recover": recover.main}


@pytest.mark.parametrize("tool", sorted(TOOLS))
@pytest.mark.parametrize("case", ["missing", "empty_dir", "file"])
def test_a_path_that_is_not_a_bag_is_a_usage_error_in_every_tool(tool, case, tmp_path, capsys):
    path = {"missing": tmp_path / "nope", "empty_dir": tmp_path, "file": tmp_path / "f.txt"}[case]
    if case == "file":
        path.write_text("not a bag\n")
    assert TOOLS[tool]([str(path)]) == EXIT_USAGE == 2
    out = capsys.readouterr()
    lines = (out.out + out.err).strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and "Traceback" not in lines[0], lines


@pytest.mark.parametrize("tool", sorted(TOOLS))
def test_a_damaged_bag_is_exit_1_in_every_tool(tool, tmp_path, capsys):
    bag = tmp_path / "run"
    bag.mkdir()
    (bag / "run_0.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 40)  # a recorder killed at once: no metadata.yaml
    assert TOOLS[tool]([str(bag)]) == EXIT_BAD_BAG == 1
    out = capsys.readouterr()
    assert "Traceback" not in out.out + out.err
    if tool != "dlo-bag-recover":
        assert f"dlo-bag-recover {bag}" in out.err  # the fix is named
