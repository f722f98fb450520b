"""Robot settings sources and the fleetgate-robot entry point's refusals."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from robot_client.__main__ import main
from robot_client.config import ConfigError, load_settings


def test_cli_beats_env_beats_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = tmp_path / "robot.toml"
    cfg.write_text('robot_id = 1\ntoken = "t"\ngrid_width = 4\ngrid_height = 3\ncell_m = 0.5\n'
                   'start_heading = "N"\n')
    monkeypatch.setenv("FLEETGATE_ROBOT_CELL_M", "0.3")
    monkeypatch.setenv("FLEETGATE_ROBOT_ROBOT_ID", "2")
    s = load_settings(["--robot-id", "5"], config_file=cfg)
    assert (s.robot_id, s.cell_m, s.grid_width, s.start_heading) == (5, 0.3, 4, "N")


def test_bad_settings_give_one_line_reasons(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="robot_id: Field required"):
        load_settings([], grid_width=3, grid_height=3, token="t")
    with pytest.raises(ConfigError, match="not found"):
        load_settings([], config_file=tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match="start_heading"):
        load_settings([], robot_id=0, token="t", grid_width=3, grid_height=3,
                      start_heading="NE")


def test_entry_point_exits_2_when_the_base_cannot_be_opened(
        capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["--robot-id", "0", "--token", "t", "--grid-width", "3", "--grid-height", "3",
               "--serial-port", "/nonexistent/kobuki", "--no-camera"])
    assert rc == 2
    assert "cannot open Kobuki serial port" in capsys.readouterr().err


def test_module_runs_with_help() -> None:
    out = subprocess.run([sys.executable, "-m", "robot_client", "--help"], capture_output=True,
                         text=True, timeout=60, check=True).stdout
    assert "--gateway-url" in out and "--robot-id" in out


def test_help_lists_config_and_log_level_and_plain_flags() -> None:
    out = subprocess.run([sys.executable, "-m", "robot_client", "--help"], capture_output=True,
                         text=True, timeout=60, check=True).stdout
    assert "--config TEXT" in out and "--log-level {DEBUG,INFO,WARNING,ERROR}" in out
    assert "[--no-camera]" in out and "--no-no-camera" not in out


def test_help_shows_placeholders_not_pydantic_type_names() -> None:
    out = subprocess.run([sys.executable, "-m", "robot_client", "--help"], capture_output=True,
                         text=True, timeout=60, check=True).stdout
    assert "--token TOKEN" in out and "--ca-file FILE" in out and "--robot-id N" in out
    for pydantic_name in ("SecretStr", "null", "{Path"):
        assert pydantic_name not in out, pydantic_name
    assert re.findall(r"--[a-z-]+ (?:str|int|float|bool)\b", out) == []
    assert "exit codes: 0 success" in out


def test_a_missing_file_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ca = tmp_path / "no-such-ca.pem"
    assert main(["--robot-id", "0", "--token", "t", "--grid-width", "2", "--grid-height", "2",
                 "--serial-port", "/dev/null", "--no-camera", "--gateway-url",
                 "wss://127.0.0.1:9/ws", "--ca-file", str(ca)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(ca) in err, err


def test_log_level_from_the_config_file(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "robot.toml"
    cfg.write_text('robot_id = 0\ntoken = "t"\ngrid_width = 3\ngrid_height = 3\n'
                   'serial_port = "/nonexistent/kobuki"\nno_camera = true\nlog_level = "LOUD"\n')
    assert main(["--config", str(cfg)]) == 2
    assert "log_level" in capsys.readouterr().err
