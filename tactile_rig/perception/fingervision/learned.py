"""What the learned FingerVision models share: feature checks, the fitting environment, their files.

A learned model (:mod:`.force_map`, :mod:`.substance`) is saved as ``<stem>.npz`` (arrays, no pickle)
and ``<stem>.json`` (the :class:`~tactile_rig.core.envelope.FileFormat` envelope and metadata), as a
GelSight calibration is. The helpers here read those files as written and check what a model needs of
them; every problem is a :class:`~tactile_rig.core.errors.CalibrationError` naming the file. Fitting
uses scikit-learn, the ``learn`` extra, imported only by the fits.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, ClassVar, Mapping, TypeVar

import numpy as np

from tactile_rig.core.envelope import FileFormat
from tactile_rig.core.errors import BadFile, CalibrationError
from tactile_rig.core.jsonable import to_jsonable

__all__ = ["SavedModel", "check_features", "checked_envelope", "feature_names", "model_paths", "one_blas_thread",
           "read_saved", "require_sklearn", "saved_array"]

M = TypeVar("M", bound="SavedModel")


def require_sklearn() -> None:
    """Fitting needs scikit-learn (the ``learn`` extra): a clear error naming the install if absent."""
    try:
        import sklearn  # noqa: F401  (optional extra, imported only to fit)
    except ModuleNotFoundError as exc:  # pragma: no cover - depends on the install
        raise ModuleNotFoundError("fitting needs scikit-learn: pip install 'tactile-rig[learn]'",
                                  name=exc.name) from exc


def one_blas_thread() -> Any:
    """Small dense problems run 10-30x slower when BLAS threads fight over a busy machine."""
    from threadpoolctl import threadpool_limits  # a dependency of scikit-learn (the learn extra)

    return threadpool_limits(limits=1, user_api="blas")


def model_paths(path: str | Path) -> tuple[Path, Path]:
    """``(<stem>.npz, <stem>.json)`` of a model named by its stem, ``.npz`` or ``.json``."""
    p = Path(path)
    stem = p.with_suffix("") if p.suffix in (".npz", ".json") else p
    return stem.with_suffix(".npz"), stem.with_suffix(".json")


def check_features(X: np.ndarray, n_features: int, who: str) -> np.ndarray:
    """``X`` as a float (n, n_features) array of finite values (one row may be given as 1-D)."""
    x = np.asarray(X, float)
    if x.ndim == 1:
        x = x[None, :]
    if x.ndim != 2 or x.shape[1] != n_features:
        raise ValueError(f"{who}: expected an (n, {n_features}) feature array, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{who}: features contain NaN or infinity")
    return x


def saved_array(arrays: Mapping[str, np.ndarray], key: str, shape: tuple[int | None, ...], source: str,
                device: str) -> np.ndarray:
    """``arrays[key]`` as float: present, finite and of ``shape`` (None: any length on that axis);
    else CalibrationError naming ``source`` and the array."""
    if key not in arrays:
        raise CalibrationError(f"{source}: the array {key!r} is missing", device=device)
    a = np.asarray(arrays[key])
    if a.dtype.kind not in "iuf":
        raise CalibrationError(f"{source}: the array {key!r} has dtype {a.dtype}; real numbers are needed",
                               device=device)
    if a.ndim != len(shape) or any(n is not None and n != m for n, m in zip(shape, a.shape)):
        want = "(" + ", ".join("N" if n is None else str(n) for n in shape) + ("," if len(shape) == 1 else "") + ")"
        raise CalibrationError(f"{source}: the array {key!r} has shape {a.shape}; the model needs {want}",
                               device=device)
    a = a.astype(float)
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"{source}: the array {key!r} holds NaN or infinity", device=device)
    return a


def checked_envelope(fmt: FileFormat, meta: object, source: str, device: str) -> dict[str, Any]:
    """The metadata of a saved model once its envelope is ``fmt``'s, else CalibrationError."""
    try:
        return fmt.check(meta, source)
    except BadFile as exc:
        raise CalibrationError(str(exc), device=device) from None


def read_saved(path: str | Path, fmt: FileFormat, device: str) -> tuple[dict[str, Any], dict[str, np.ndarray], Path]:
    """The metadata (envelope checked) and arrays of ``<stem>.json`` + ``.npz`` as written (no pickle,
    no size bounds: the bench's checked loaders bound them first); CalibrationError naming the file."""
    npz, js = model_paths(path)
    if not js.is_file():
        raise CalibrationError(f"model file {js} does not exist", device=device)
    try:
        meta = json.loads(js.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise CalibrationError(f"model file {js} is not valid JSON: {exc}", device=device) from None
    meta = checked_envelope(fmt, meta, str(js), device)
    if not npz.is_file():
        raise CalibrationError(f"{fmt.what} arrays {npz} are missing (the .json is there)", device=device)
    try:
        with np.load(npz, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError) as exc:
        raise CalibrationError(f"{npz} is not a readable {fmt.what} ({exc})", device=device) from None
    return meta, arrays, npz


def feature_names(meta: Mapping[str, Any], default: tuple[str, ...], source: str, device: str) -> tuple[str, ...]:
    """The feature names a saved model's metadata lists (``default`` when it lists none): one name per
    feature the model was fitted on; else CalibrationError naming ``source``."""
    names = meta.get("features", list(default))
    if not (isinstance(names, list) and len(names) == len(default) and all(isinstance(n, str) for n in names)):
        raise CalibrationError(f"{source}: 'features' is {names!r}; {len(default)} names ({', '.join(default)}) "
                               "are needed", device=device)
    return tuple(names)


class SavedModel:
    """What every learned model does with its files: :meth:`save` writes ``<stem>.npz`` (its arrays, no
    pickle) and ``<stem>.json`` (its envelope and metadata); :meth:`load` reads them back as written
    and hands them to the model's own checks. A model sets ``FILE`` (its envelope), ``DEVICE`` (the
    name its errors carry) and provides :meth:`to_arrays`, :meth:`metadata` and :meth:`from_saved`."""

    FILE: ClassVar[FileFormat]
    DEVICE: ClassVar[str]

    def to_arrays(self) -> dict[str, Any]:
        """What ``<stem>.npz`` holds."""
        raise NotImplementedError

    def metadata(self, arrays_name: str) -> dict[str, Any]:
        """What ``<stem>.json`` holds (``arrays_name``: the ``.npz`` beside it)."""
        raise NotImplementedError

    @classmethod
    def from_saved(cls: type[M], meta: Mapping[str, Any], arrays: Mapping[str, np.ndarray], source: str = "") -> M:
        """The model from its metadata and arrays, every one checked; CalibrationError naming ``source``."""
        raise NotImplementedError

    def save(self, path: str | Path) -> tuple[Path, Path]:
        """Write ``<stem>.npz`` (arrays) and ``<stem>.json`` (metadata); no pickle anywhere."""
        npz, js = model_paths(path)
        npz.parent.mkdir(parents=True, exist_ok=True)
        np.savez(npz, **self.to_arrays())
        js.write_text(json.dumps(to_jsonable(self.metadata(npz.name)), indent=1) + "\n", encoding="utf-8")
        return npz, js

    @classmethod
    def load(cls: type[M], path: str | Path) -> M:
        """The model saved at ``path`` (stem, ``.npz`` or ``.json``); CalibrationError naming the file."""
        meta, arrays, npz = read_saved(path, cls.FILE, cls.DEVICE)
        return cls.from_saved(meta, arrays, str(npz))
