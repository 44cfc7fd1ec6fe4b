"""World files: the lab loads; bad files name the file, the marker and the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from icefloe.errors import ConfigError
from icefloe.worldmap import load_world


def test_the_lab_world_loads() -> None:
    lab = load_world("lab")
    assert lab.name == "lab" and len(lab.markers) == 12
    assert lab.marker(1).size == 0.12 and lab.marker(99) is None


BOARD = "columns = 10\nrows = 7\nsquare = 0.025\nx = 0.5\ny = 0.0\nz = 0.12\nyaw = 3.14\n"


GOOD = "id = 3\nx = 1.0\ny = 0.0\nz = 0.1\nsize = 0.1\nyaw = 0.0\n"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (f"[[marker]]\n{GOOD}[[marker]]\n{GOOD}", "marker[1].id: id 3 is already used by marker[0]"),
        (f"[[marker]]\n{GOOD.replace('size = 0.1', 'size = 0.0')}", "marker[0].size: Expected `float` > 0.0"),
        (f"[[marker]]\n{GOOD.replace('x = 1.0', 'x = nan')}", "marker[0]: `x` must be a finite number"),
        (f"[[marker]]\n{GOOD.replace('id = 3', 'id = -1')}", "marker[0].id: Expected `int` >= 0"),
        (f"[[marker]]\n{GOOD}colour = 1\n", "[marker[0]]: Object contains unknown field `colour`"),
        (f"[[marker]]\n{GOOD.replace('yaw = 0.0', '')}", "marker[0]: Object missing required field `yaw`"),
        (f"[[board]]\n{BOARD.replace('columns = 10', 'columns = 2')}", "board[0].columns: Expected `int` >= 3"),
        (f"[[board]]\n{BOARD}kind = \"charuco\"\n", "board[0]: `marker` must be > 0 and smaller than `square`"),
        (f"[[board]]\n{BOARD}kind = \"checkers\"\n", "board[0].kind: Invalid enum value 'checkers'"),
        (f"[[board]]\n{BOARD.replace('square = 0.025', 'square = inf')}", "board[0]: `square` must be a finite"),
    ],
)
def test_bad_world_files_name_the_marker_and_key(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "w.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_world(str(path))
    assert str(err.value).startswith(f"{path}: ")
    assert message in str(err.value), str(err.value)


def test_the_calibration_world_stands_three_boards() -> None:
    """The chessboard, the ChArUco board, and the ChArUco board of the lab's own markers (ids 40-49 of
    DICT_4X4_50, which the lab's map does not use) that measures the marker detector's inset."""
    world = load_world("calibration")
    assert [b.kind for b in world.boards] == ["chessboard", "charuco", "charuco"] and world.markers == ()
    lab_ids = {m.id for m in load_world("lab").markers}
    lab_board = world.boards[2]
    assert lab_board.dictionary == "DICT_4X4_50" and lab_board.first_id == 40
    assert not lab_ids & set(range(40, 40 + lab_board.columns * lab_board.rows // 2))
