"""The simulator with the gateware as its icoBoard, in this process: selection, handles, errors."""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest

from icefloe import config as config_mod
from icefloe.errors import BadPayload, ConfigError
from icefloe.schemas import messages as m
from icefloe.services.sim.simulator import Simulator
from icefloe.sim.icoboard_gateware import GatewareBoardModel
from icefloe.wire.icoboard import Op, Wire


def _config(tmp_path: Path, **sim: object):
    cfg = config_mod.load("sim-gateware")
    board = msgspec.structs.replace(cfg.board, sim_socket=str(tmp_path / "ico.sock"))
    return msgspec.structs.replace(cfg, board=board, run_dir=str(tmp_path),  # the socket is in the run folder
                                   sim=msgspec.structs.replace(cfg.sim, seed=1, **sim))


def test_the_config_picks_the_gateware_and_its_handles_work(tmp_path: Path) -> None:
    sim = Simulator(_config(tmp_path))
    try:
        model = sim.board.model
        assert isinstance(model, GatewareBoardModel) and sim.kind == "icoboard-v2"
        wire = Wire(2)
        start = wire.parse_reply(Op.START, model.exchange(wire.request(Op.START, seq=1), 0.0))
        wire.check_start(start)                      # the descriptor of the config's peripheral list
        sim.control(m.SimControl(action="inject_noise", count=1, direction="rx"))
        model.exchange(wire.request(Op.RECEIVE, seq=2), 0.0)   # arrives with a flipped bit
        sim.clock.step()
        assert sim.state().bad_frames == 1
        with pytest.raises(BadPayload, match="peripheral list it was built for"):
            sim.control(m.SimControl(action="force_descriptor", sensors=3, actuators=2))
        sim.control(m.SimControl(action="force_descriptor", sensors=-1, actuators=-1))  # the truth: fine
    finally:
        sim.close()


def test_the_gateware_speaks_protocol_2_only(tmp_path: Path) -> None:
    cfg = _config(tmp_path)
    cfg = msgspec.structs.replace(cfg, board=msgspec.structs.replace(cfg.board, protocol=1))
    with pytest.raises(ConfigError, match="protocol v2 only"):
        Simulator(cfg)
