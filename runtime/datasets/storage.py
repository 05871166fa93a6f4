"""Datasets on disk: :class:`~.collect.Episodes` as a Minari dataset or one ``.npz``, with provenance and reference
scores, written atomically; the loader that refuses a dataset of another spec or env version (README.md here).

    path = write_dataset(eps, "out/", name="optimal")                # out/myriad/van_der_pol/optimal-v0/
    eps, meta = load_dataset(path, "van_der_pol")                    # ValueError: another spec or env version
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import shutil
import tempfile
import warnings
import zipfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_write_bytes
from ..loader import load
from ..system import System
from .collect import Episodes

__all__ = ["FORMAT", "FORMATS", "dataset_id", "dataset_path", "provenance", "write_dataset", "load_dataset"]

FORMAT = 1  # of our provenance record: bump with a change of layout
FORMATS = ("minari", "npz")
_ARRAYS = ("observations", "actions", "rewards", "terminations", "truncations", "states")


def _env_version() -> int:
    from ..rl.reference import ENV_VERSION

    return ENV_VERSION


def dataset_id(system: str, name: str) -> str:
    """Minari's id of a dataset: ``myriad/<system>/<name>-v<env version>`` (namespace, environment, dataset)."""
    return f"myriad/{system}/{name}-v{_env_version()}"


def dataset_path(out: str | os.PathLike, system: str, name: str, fmt: str = "minari") -> Path:
    """Where :func:`write_dataset` puts a dataset of ``system`` named ``name`` under ``out``."""
    if fmt == "npz":
        return Path(out) / f"{system}-{name}-v{_env_version()}.npz"
    return Path(out) / dataset_id(system, name)


def _spec_text(system: System) -> str | None:
    """The spec's text when its file is found and is the one the system was compiled from (same SHA-256)."""
    root = Path(__file__).resolve().parents[2]
    for path in (Path(system.spec_file), root / system.spec_file):
        if path.is_file():
            data = path.read_bytes()
            if hashlib.sha256(data).hexdigest() == system.spec_sha256:
                return data.decode("utf-8")
    return None


def _reference(system: System, episodes: Episodes) -> dict[str, float]:
    """The env's reference returns: the optimum's (``ref_max_score``) and the uniform random policy's mean
    (``ref_min_score``), from ``rl.reference`` in the dataset's env settings."""
    from ..rl.env import EnvOptions
    from ..rl.reference import reference_record

    record = reference_record(system, EnvOptions(**episodes.info["options"]))
    return {"ref_min_score": -float(record["random"]["cost"]), "ref_max_score": -float(record["optimal"]["cost"])}


def provenance(episodes: Episodes, system: System, gym_id: str | None) -> dict[str, Any]:
    """What a dataset records of itself: our format, the spec (SHA-256, name, text when found), the env (version,
    options, Gymnasium id), the policy and its settings, the perturbation and the seed, and the software."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        ours = version("myriad-control")
    except PackageNotFoundError:
        ours = None
    info = episodes.info
    return {"format": FORMAT, "system": system.name, "spec_sha256": system.spec_sha256,
            "spec_text": _spec_text(system), "env_version": _env_version(), "gymnasium_id": gym_id,
            "env_options": info["options"], "policy": info["policy"], "settings": info["settings"],
            "perturb": info["perturb"], "seed": info["seed"], "episodes": info["episodes"],
            "collection": {k: v for k, v in info.items() if k not in ("options", "settings", "perturb")},
            "myriad_version": ours, "params": {k: v.tolist() for k, v in episodes.params.items()}}


def _gym_spec(system: System, target: Any, options: dict[str, Any]):
    """The Gymnasium ``EnvSpec`` that remakes the env (``rl.register``'s id, the options as its keywords), or None
    where its keywords are not plain data (a system given as an object)."""
    import dataclasses

    import gymnasium

    from ..rl import register

    spec = gymnasium.spec(register(target if target is not None else system))
    spec = dataclasses.replace(spec, kwargs={**spec.kwargs, **options})
    try:
        spec.to_json()
    except (TypeError, ValueError):
        return None
    return spec


def _spaces(system: System, options: dict[str, Any]):
    """float64 ``Box`` spaces (the data is float64; the Gymnasium env's float32 bounds, widened)."""
    import gymnasium

    from ..rl.env import Env, EnvOptions

    env = Env(system, EnvOptions(**options))
    lo, hi = env.observation_bounds
    alo, ahi = env.action_bounds
    return (gymnasium.spaces.Box(lo, hi, dtype=np.float64),
            gymnasium.spaces.Box(np.asarray(alo, np.float64), np.asarray(ahi, np.float64), dtype=np.float64))


@contextmanager
def _minari_root(path: Path):
    """Minari writes under ``$MINARI_DATASETS_PATH``: point it at ``path`` for the duration."""
    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(path)
    try:
        yield
    finally:
        if old is None:
            del os.environ["MINARI_DATASETS_PATH"]
        else:
            os.environ["MINARI_DATASETS_PATH"] = old


def _buffers(episodes: Episodes) -> list:
    from minari.data_collector import EpisodeBuffer

    return [EpisodeBuffer(id=e, observations=episodes.observations[e], actions=episodes.actions[e],
                          rewards=episodes.rewards[e], terminations=episodes.terminations[e],
                          truncations=episodes.truncations[e], infos={"state": episodes.states[e]})
            for e in range(len(episodes))]


def _write_minari(episodes: Episodes, system: System, out: Path, name: str, target: Any) -> Path:
    import minari

    ident = dataset_id(system.name, name)
    final = out / ident
    options = episodes.info["options"]
    spec = _gym_spec(system, target, options)
    obs_space, act_space = _spaces(system, options)
    meta = provenance(episodes, system, spec.id if spec is not None else None)
    out.mkdir(parents=True, exist_ok=True)
    # Absolute: Minari joins a relative root onto itself (`--out data/` failed with FileNotFoundError).
    tmp = Path(tempfile.mkdtemp(prefix=".dataset-", dir=out)).resolve()
    try:
        with _minari_root(tmp), warnings.catch_warnings():
            # Minari asks for an author e-mail and a code permalink (a dataset written here has neither).
            warnings.simplefilter("ignore", UserWarning)
            minari.create_dataset_from_buffers(
                ident, _buffers(episodes), env=spec, eval_env=spec, algorithm_name=f"myriad/{meta['policy']}",
                author="myriad", observation_space=obs_space, action_space=act_space,
                description=f"{meta['policy']} policy on {system.name}: {system.title}",
                **_reference(system, episodes))
        data = tmp / ident / "data"
        metadata = json.loads((data / "metadata.json").read_text())
        metadata["myriad"] = meta
        (data / "metadata.json").write_text(json.dumps(metadata, indent=1, sort_keys=True))
        final.parent.mkdir(parents=True, exist_ok=True)
        for level in range(1, len(Path(ident).parts)):  # the namespaces' metadata, for minari's listing
            src = tmp.joinpath(*Path(ident).parts[:level], "namespace_metadata.json")
            dst = out.joinpath(*Path(ident).parts[:level], "namespace_metadata.json")
            if src.is_file() and not dst.exists():
                shutil.copyfile(src, dst)
        os.rename(tmp / ident, final)  # atomic: the folder appears whole or not at all (OSError if it exists)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return final


def _npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """``np.savez``'s layout with fixed entry times (``np.savez`` stamps the clock), so equal data, equal bytes."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for key in sorted(arrays):
            entry = io.BytesIO()
            np.lib.format.write_array(entry, np.asanyarray(arrays[key]), allow_pickle=False)
            archive.writestr(zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0)), entry.getvalue())
    return buffer.getvalue()


def _write_npz(episodes: Episodes, system: System, out: Path, name: str, target: Any) -> Path:
    final = dataset_path(out, system.name, name, "npz")
    spec = _gym_spec(system, target, episodes.info["options"])
    meta = {**provenance(episodes, system, spec.id if spec is not None else None), **_reference(system, episodes)}
    arrays = {k: getattr(episodes, k) for k in _ARRAYS}
    arrays["metadata"] = np.array(json.dumps(meta, sort_keys=True))
    out.mkdir(parents=True, exist_ok=True)
    return atomic_write_bytes(final, _npz_bytes(arrays))


def write_dataset(episodes: Episodes, out: str | os.PathLike, name: str | None = None, fmt: str = "minari",
                  target: Any = None) -> Path:
    """Write ``episodes`` under the folder ``out``: Minari's layout (``out/myriad/<system>/<name>-v<env version>/``,
    loadable with ``MINARI_DATASETS_PATH=out`` and ``minari.load_dataset(id)``) or one ``.npz``; returns its path.

    Args:
        name: the dataset's name (default: the policy's).
        fmt: ``"minari"`` or ``"npz"``.
        target: what the episodes were collected on (a spec path, a name or the system), for the Gymnasium id
            that remakes the env (a system object has none: the spec's hash and text identify it); default what
            :func:`~.collect.collect` was given.

    Raises:
        FileExistsError: the dataset exists already (never overwritten).
    """
    if fmt not in FORMATS:
        raise ValueError(f"write_dataset: unknown format {fmt!r}; one of {', '.join(FORMATS)}")
    target = target if target is not None else episodes.info.get("target")
    if isinstance(target, System):
        system = target
    else:
        system = load(target if target is not None else episodes.info["system"])
    if system.spec_sha256 != episodes.info["spec_sha256"]:
        raise ValueError(f"write_dataset: the episodes were collected on spec {episodes.info['spec_sha256'][:12]}, "
                         f"the target is {system.spec_sha256[:12]}")
    name = episodes.info["policy"] if name is None else name
    out = Path(out)
    if dataset_path(out, system.name, name, fmt).exists():
        raise FileExistsError(f"{dataset_path(out, system.name, name, fmt)} exists; choose another --out or --name")
    return (_write_npz if fmt == "npz" else _write_minari)(episodes, system, out, name, target)


def _check(meta: dict[str, Any], path: Path, system: System | None) -> None:
    """Refuse a dataset of another format, env version or spec, naming both sides."""
    if meta.get("format") != FORMAT or meta.get("env_version") != _env_version():
        raise ValueError(f"{path}: a dataset of format {meta.get('format')} and env version "
                         f"{meta.get('env_version')}; this myriad reads format {FORMAT}, env version "
                         f"{_env_version()}: collect it again with `myriad dataset`")
    if system is not None and meta.get("spec_sha256") != system.spec_sha256:
        raise ValueError(f"{path}: a dataset of {meta.get('system')} (spec sha256 {meta.get('spec_sha256', '')[:12]}"
                         f"...), not of {system.name} (spec sha256 {system.spec_sha256[:12]}...): the spec differs; "
                         f"collect a dataset of this spec with `myriad dataset`")


def _episodes(arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> Episodes:
    params = {k: np.asarray(v, np.float64) for k, v in meta["params"].items()}
    info = {**meta["collection"], "options": meta["env_options"], "settings": meta["settings"],
            "perturb": meta["perturb"]}
    return Episodes(**arrays, returns=arrays["rewards"].sum(axis=1), params=params, info=info)


def _load_minari(path: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    import minari

    data = path / "data" if (path / "data").is_dir() else path
    metadata = json.loads((data / "metadata.json").read_text())
    if "myriad" not in metadata:
        raise ValueError(f"{path}: a Minari dataset without myriad's provenance; not written by `myriad dataset`")
    dataset = minari.MinariDataset(data)
    eps = list(dataset.iterate_episodes())
    arrays = {"observations": np.stack([e.observations for e in eps]), "actions": np.stack([e.actions for e in eps]),
              "rewards": np.stack([e.rewards for e in eps]), "terminations": np.stack([e.terminations for e in eps]),
              "truncations": np.stack([e.truncations for e in eps]),
              "states": np.stack([e.infos["state"] for e in eps])}
    return arrays, metadata["myriad"]


def load_dataset(path: str | os.PathLike, system: System | str | None = None) -> tuple[Episodes, dict[str, Any]]:
    """Read a dataset :func:`write_dataset` wrote (its Minari folder or its ``.npz``): ``(episodes, provenance)``.

    Raises:
        ValueError: another format or env version, or (``system`` given) another spec, with both named.
        FileNotFoundError: nothing at ``path``.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no dataset at {path}")
    if path.is_dir():
        arrays, meta = _load_minari(path)
    else:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: np.asarray(npz[k]) for k in _ARRAYS}
            meta = json.loads(str(npz["metadata"]))
    _check(meta, path, None if system is None else (load(system) if isinstance(system, str) else system))
    return _episodes(arrays, meta), meta
