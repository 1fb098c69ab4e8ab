"""The battery commands' authentication (nni_msgs_adapter.ros.command_auth): keys, seals, replays, key files."""

from __future__ import annotations

import os
import subprocess
import sys
import stat

import pytest

from nni_msgs_adapter.ros import command_auth
from nni_msgs_adapter.ros.command_auth import AUTHENTIC, REPLAYED, UNAUTHENTICATED, CommandSigner, CommandVerifier

KEY = bytes(range(32))
TOPIC = "/gen1/battery/command"


def test_a_controllers_commands_verify_in_order_and_nothing_else_does():
    signer, verifier = CommandSigner(KEY, TOPIC, first_sequence=100), CommandVerifier(KEY, TOPIC)
    first, second = signer.seal(1_000, 0.25), signer.seal(2_000, -0.1)
    assert len(first) == command_auth.SEAL_LENGTH and first[:17] == b"%016x|" % 101
    assert verifier.check(first, 1_000, 0.25) == AUTHENTIC
    assert verifier.check(second, 2_000, -0.1) == AUTHENTIC
    assert verifier.check(first, 1_000, 0.25) == REPLAYED  # captured and sent again
    assert verifier.check(second, 2_000, -0.1) == REPLAYED
    third = signer.seal(3_000, 0.3)
    assert verifier.check(third, 3_000, 5.0) == UNAUTHENTICATED  # the power changed on the way
    assert verifier.check(third, 3_001, 0.3) == UNAUTHENTICATED  # the stamp changed
    assert verifier.check(third, 3_000, 0.3) == AUTHENTIC  # the forgeries did not burn its sequence


@pytest.mark.parametrize("seal", [None, b"", b"0" * command_auth.SEAL_LENGTH, b"g" * 16 + b"|" + b"0" * 64,
                                  b"%016x|" % 2**63 + b"0" * 63])
def test_a_missing_or_malformed_seal_is_unauthenticated(seal):
    assert CommandVerifier(KEY, TOPIC).check(seal, 0, 0.0) == UNAUTHENTICATED


def test_a_seal_holds_on_its_own_topic_and_under_its_own_key_only():
    seal = CommandSigner(KEY, TOPIC, 0).seal(5, 0.1)
    assert CommandVerifier(KEY, "/gen2/battery/command").check(seal, 5, 0.1) == UNAUTHENTICATED
    assert CommandVerifier(bytes(32), TOPIC).check(seal, 5, 0.1) == UNAUTHENTICATED
    assert CommandVerifier(KEY, TOPIC).check(seal, 5, 0.1) == AUTHENTIC


def test_a_restarted_controller_counts_on_from_its_clock():
    verifier = CommandVerifier(KEY, TOPIC)
    assert verifier.check(CommandSigner(KEY, TOPIC).seal(1, 0.0), 1, 0.0) == AUTHENTIC
    assert verifier.check(CommandSigner(KEY, TOPIC).seal(2, 0.0), 2, 0.0) == AUTHENTIC


def test_a_run_key_is_private_fresh_and_gone_after_the_run():
    with command_auth.run_key() as path, command_auth.run_key() as other:
        assert stat.S_IMODE(path.stat().st_mode) == 0o600 and stat.S_IMODE(path.parent.stat().st_mode) == 0o700
        assert command_auth.read_key(path) != command_auth.read_key(other)
        assert command_auth.key_from_environment({command_auth.KEY_FILE_ENV: str(path)}) == command_auth.read_key(path)
    assert not path.exists() and not path.parent.exists()
    assert command_auth.key_from_environment({}) is None


def test_a_key_file_others_can_read_or_of_another_length_is_refused(tmp_path):
    loose = tmp_path / "loose.key"
    loose.write_bytes(KEY)
    os.chmod(loose, 0o644)
    with pytest.raises(command_auth.KeyFileError, match="readable or writable by group or others .*chmod 600"):
        command_auth.read_key(loose)
    short = tmp_path / "short.key"
    short.write_bytes(KEY[:10])
    os.chmod(short, 0o600)
    with pytest.raises(command_auth.KeyFileError, match="32 random bytes expected, the file has 10"):
        command_auth.read_key(short)
    with pytest.raises(command_auth.KeyFileError, match="cannot open the key file"):
        command_auth.read_key(tmp_path / "missing.key")
    with pytest.raises(command_auth.KeyFileError, match="not a regular file"):
        command_auth.read_key(tmp_path)


def test_a_killed_runs_key_folder_is_removed_at_the_next_start_and_a_running_ones_is_kept(tmp_path, monkeypatch):
    monkeypatch.setattr(command_auth.tempfile, "tempdir", str(tmp_path))
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead = tmp_path / f"{command_auth.KEY_FOLDER_PREFIX}{int(gone.stdout)}-abc"
    dead.mkdir(mode=0o700)
    (dead / "command.key").write_bytes(KEY)
    alive = tmp_path / f"{command_auth.KEY_FOLDER_PREFIX}{os.getppid()}-def"
    alive.mkdir(mode=0o700)
    path = command_auth.new_key_file()
    try:
        assert not dead.exists() and alive.exists()
        assert path.parent.name.startswith(f"{command_auth.KEY_FOLDER_PREFIX}{os.getpid()}-")
    finally:
        command_auth.remove_key_file(path)
