"""The policy folder's one reader: a shipped policy read through it, and clear errors naming the file."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from compare.scenarios.fingerprint import policy_fingerprint
from rl.pilots.learned import load_policy
from rl.policies.folder import (
    CHECKPOINT_FILES,
    CURVE_COLUMNS,
    DEFAULT_POLICY_DIR,
    FLYING_FILES,
    SHIPPED_POLICIES,
    NetworkConfig,
    PolicyFolder,
    Provenance,
    shipped_policy_dir,
)
from rl.training import loop


@pytest.mark.parametrize("vehicle", sorted(SHIPPED_POLICIES))
def test_a_shipped_policy_reads_through_the_folder(vehicle: str) -> None:
    pf = PolicyFolder.open(shipped_policy_dir(vehicle))
    assert pf.path == SHIPPED_POLICIES[vehicle]
    for path in (pf.model, pf.obs_norm, pf.config_file, pf.vec_normalize, pf.curriculum, pf.reward_curve,
                 pf.provenance_file):
        assert path.is_file(), path
    cfg = pf.config()
    assert cfg.nav.vehicle == vehicle and cfg.preset == "paper" and list(cfg.ppo["net_arch"]) == [128, 128]
    assert cfg.network == NetworkConfig((128, 128), -1.0)  # the paper's network
    prov = pf.provenance()
    assert isinstance(prov, Provenance) and prov.method == "PPO from scratch"
    assert all(isinstance(v, int) for v in (prov.seed, prov.timesteps, prov.kept_timesteps))
    assert 0 < prov.kept_timesteps <= prov.timesteps and prov.wall_time_s > 0
    assert prov.command.startswith("uam-compare train") and prov.raw["machine"]["cpus"] >= 1
    header = pf.reward_curve.read_text().splitlines()[0]
    assert tuple(header.split(",")) == CURVE_COLUMNS
    # the pilot's loader and the run's fingerprint read the same folder through the same names
    assert load_policy(pf.path).nav == cfg.nav
    assert tuple(policy_fingerprint(pf.path)) == FLYING_FILES


def test_names_are_defined_once() -> None:
    assert PolicyFolder.open().path == DEFAULT_POLICY_DIR == SHIPPED_POLICIES["small_quad"]
    assert loop.CURVE_COLUMNS is CURVE_COLUMNS
    assert set(FLYING_FILES) <= set(CHECKPOINT_FILES)
    assert PolicyFolder("x").checkpoint(2_000_128).path == Path("x/checkpoints/step_00002000128")


@pytest.mark.parametrize("missing", FLYING_FILES)
def test_a_folder_missing_a_file_names_it(tmp_path: Path, missing: str) -> None:
    for name in FLYING_FILES:
        if name != missing:
            shutil.copy(DEFAULT_POLICY_DIR / name, tmp_path / name)
    with pytest.raises(ValueError, match=rf"^{tmp_path}: not a policy folder \({missing} is missing\)$"):
        PolicyFolder.open(tmp_path)
    with pytest.raises(ValueError, match=rf"\({missing} is missing\)"):
        load_policy(tmp_path)


@pytest.mark.parametrize("text, why", [
    ("[1, 2]", "list indices"),
    ("{not json", "Expecting property name"),
    ('{"ppo": {}}', "'nav'"),
    ('{"nav": {}, "ppo": [128]}', "'ppo' must be an object, got list"),
])
def test_a_bad_config_names_the_file(tmp_path: Path, text: str, why: str) -> None:
    (tmp_path / "config.json").write_text(text)
    with pytest.raises(ValueError) as exc:
        PolicyFolder(tmp_path).config()
    assert str(exc.value).startswith(f"{tmp_path / 'config.json'}: not a policy configuration (")
    assert why in str(exc.value)


def _shipped_config() -> dict:
    return json.loads((DEFAULT_POLICY_DIR / "config.json").read_text())


@pytest.mark.parametrize(("edit", "why"), [
    (lambda c: c["ppo"].pop("net_arch"), "'net_arch'"),
    (lambda c: c["ppo"].update(net_arch=[]), "ppo.net_arch must be 1 to 8 layer sizes of 1 to 4096 units, got []"),
    (lambda c: c["ppo"].update(net_arch=[128, 10**9]), "ppo.net_arch must be 1 to 8 layer sizes"),
    (lambda c: c["ppo"].update(net_arch="128"), "ppo.net_arch must be"),
    (lambda c: c["ppo"].update(net_arch=[128, 12.5]), "ppo.net_arch must be"),
    (lambda c: c["ppo"].update(log_std_init=1e300), "ppo.log_std_init must be a number in [-20, 5], got 1e+300"),
    (lambda c: c["ppo"].update(log_std_init="x"), "ppo.log_std_init must be a number"),
    (lambda c: c["nav"].update(vehicle="/etc/passwd"), "nav.vehicle '/etc/passwd' is not a vehicle preset"),
    (lambda c: c["nav"].update(vehicle="../../my.yaml"), "is not a vehicle preset (small_quad, uam_multicopter"),
])
def test_a_config_with_an_absurd_network_or_a_vehicle_file_is_refused(tmp_path: Path, edit, why: str) -> None:
    """What config.json may say is bounded: the network's shape, its noise, and a vehicle preset by name (a
    shared policy folder must not point the reader at any file on the machine)."""
    for name in FLYING_FILES:
        shutil.copy(DEFAULT_POLICY_DIR / name, tmp_path / name)
    config = _shipped_config()
    edit(config)
    (tmp_path / "config.json").write_text(json.dumps(config))
    with pytest.raises(ValueError) as exc:
        load_policy(tmp_path)
    assert str(exc.value).startswith(f"{tmp_path / 'config.json'}: not a policy configuration (")
    assert why in str(exc.value)


def test_non_finite_weights_are_refused_naming_the_tensor(tmp_path: Path) -> None:
    import io
    import zipfile

    import torch

    for name in FLYING_FILES:
        shutil.copy(DEFAULT_POLICY_DIR / name, tmp_path / name)
    with zipfile.ZipFile(DEFAULT_POLICY_DIR / "model.zip") as z:
        entries = {n: z.read(n) for n in z.namelist()}
    state = torch.load(io.BytesIO(entries["policy.pth"]), weights_only=True)
    state["action_net.0.bias"][1] = float("nan")
    buf = io.BytesIO()
    torch.save(state, buf)
    entries["policy.pth"] = buf.getvalue()
    with zipfile.ZipFile(tmp_path / "model.zip", "w") as z:
        for n, data in entries.items():
            z.writestr(n, data)
    with pytest.raises(ValueError, match=r"model\.zip: policy\.pth's action_net\.0\.bias holds non-finite weights"):
        load_policy(tmp_path)


def test_provenance_absent_unreadable_and_loosely_typed(tmp_path: Path) -> None:
    pf = PolicyFolder(tmp_path)
    assert pf.provenance() is None  # an older folder, or a run still training
    pf.provenance_file.write_text("{}")
    assert pf.provenance() is None  # nothing recorded
    pf.provenance_file.write_text("[1]")
    with pytest.raises(ValueError, match=r"provenance\.json: not a JSON object"):
        pf.provenance()
    pf.provenance_file.write_text("{oops")
    with pytest.raises(ValueError, match=r"provenance\.json: unreadable"):
        pf.provenance()
    pf.provenance_file.write_text(json.dumps({"seed": True, "timesteps": 2.0e6, "kept_timesteps": 1.5,
                                              "wall_time_s": 12, "method": 3, "preset": "paper", "x": 1}))
    prov = pf.provenance()
    assert (prov.seed, prov.timesteps, prov.kept_timesteps, prov.wall_time_s) == (None, 2_000_000, None, 12.0)
    assert (prov.method, prov.preset, prov.raw["x"]) == (None, "paper", 1)
