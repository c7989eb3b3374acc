"""A user's filter seen through the filter protocol: its worker (:mod:`.host`) started
with the submission's private copy (:mod:`.submission`), its module imported, its filter
constructed and called.

:class:`RemoteFilter` is :class:`~ekfviz.filters.protocol.SlamFilter` on this side: the
runner drives it as any other filter; :class:`WorkerFactory` makes them, a worker each,
and owns the private copy they see. Numpy only.
"""

from __future__ import annotations

import os
import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ekfviz.core.params import FilterParams
from ekfviz.core.types import FloatArray, IntArray
from ekfviz.filters.protocol import Capabilities
from ekfviz.models.kalman import measurement_noise, motion_noise, prior_covariance
from ekfviz.sandbox import bwrap
from ekfviz.sandbox.host import (
    Output,
    WorkerFault,
    WorkerProcess,
    load_limit_name,
    load_timeout,
)
from ekfviz.sandbox.options import WorkerOptions
from ekfviz.sandbox.submission import (
    Submission,
    SubmissionRefused,
    copy,
    private_folder,
    remove,
    survey,
)
from ekfviz.sandbox.text import printable


@dataclass(frozen=True, slots=True)
class Target:
    """What the worker loads: a file (``path``) or an importable ``module``, and the class
    ``name`` in it (None: a course module of functions).

    :param folder: first on the worker's ``sys.path`` (None: the file's folder, else the
        working directory)
    :param submission: what the sandbox shows of the caller's files (None: the file's
        folder, its Python files)
    """

    path: str | None
    module: str | None
    name: str | None
    folder: str | None = None
    submission: Submission | None = None

    @property
    def import_folder(self) -> str:
        """The folder the worker imports the user's module beside."""
        if self.folder:
            return self.folder
        return os.path.dirname(os.path.abspath(self.path)) if self.path else os.getcwd()

    def describe(self) -> str:
        where = self.path or self.module or "?"
        return f"{where}:{self.name}" if self.name else where


class LoadedWorker:
    """A worker with the user's module imported, not yet constructed.

    :param process: a worker already started with ``mounts`` (its interpreter and numpy
        loaded, waiting for a module), or None to start one
    :raises WorkerFault: the module cannot be imported, or lacks what it needs
    """

    def __init__(
        self,
        target: Target,
        options: WorkerOptions,
        label: str,
        mounts: Sequence[bwrap.Mount] = (),
        process: WorkerProcess | None = None,
    ) -> None:
        self.process = process if process is not None else WorkerProcess(options, label, mounts)
        self.target = target
        sys_path = [target.import_folder]
        header = {"op": "load", "path": target.path, "module": target.module,
                  "name": target.name, "sys_path": sys_path}  # fmt: skip
        try:
            answer, _ = self.process.request(header, [], "import", timeout_s=load_timeout(options),
                                             limit_name=load_limit_name(options))  # fmt: skip
        except WorkerFault:
            self.process.close()
            raise
        self.style = str(answer["style"])
        caps = answer["capabilities"]
        self.capabilities = Capabilities(
            takes_dt=bool(caps["takes_dt"]),
            removes_landmarks=bool(caps["removes_landmarks"]),
            offline=bool(caps["offline"]),
        )


def worker_noise(params: FilterParams) -> dict[str, list[list[float]]]:
    """Q, R and the prior's covariance as a worker takes them (it does no filter math)."""
    return {
        "Q": motion_noise(params.sigma_x, params.sigma_y, params.sigma_alpha).tolist(),
        "R": measurement_noise(params.sigma_bearing, params.sigma_range).tolist(),
        "prior": prior_covariance(params.init_pose_sigma).tolist(),
    }


class RemoteFilter:
    """A user's filter running in a worker, seen through the filter protocol.

    ``x``, ``P`` and ``landmark_ids`` are the state the worker sent after the last call;
    ``seconds`` the time spent in the filter's own calls (construction excluded).
    """

    def __init__(self, loaded: LoadedWorker, params: FilterParams) -> None:
        self._worker = loaded.process
        self.capabilities = loaded.capabilities
        self.style = loaded.style
        self.seconds = 0.0
        self.convention: dict[str, str | None] = {}
        self.measurement_noise: FloatArray | None = None
        self.motion_noise: FloatArray | None = None
        self.poses_xytheta: FloatArray | None = None
        values = params.as_dict()
        answer, arrays = self._worker.request(
            {"op": "construct", "params": values, "noise": worker_noise(params)}, [],
            "construction",
            timeout_s=load_timeout(self._worker.options),
            limit_name=load_limit_name(self._worker.options),
        )  # fmt: skip
        self._take(answer, arrays)
        self.seconds = 0.0

    @property
    def output(self) -> Output:
        return self._worker.output

    def _take(self, answer: dict[str, Any], arrays: list[np.ndarray[Any, Any]]) -> None:
        self.x: FloatArray = arrays[0]
        self.P: FloatArray = arrays[1]
        self.landmark_ids: IntArray = np.array(answer["ids"], dtype=np.int64)
        self.seconds += float(answer.get("seconds", 0.0))
        if "convention" in answer:
            self.convention = dict(answer["convention"])
        for name, array in zip(answer.get("extra", []), arrays[2:], strict=False):
            if name == "measurement_noise":
                self.measurement_noise = np.array(array, dtype=np.float64)
            elif name == "motion_noise":
                self.motion_noise = np.array(array, dtype=np.float64)
            elif name == "poses_xytheta":
                self.poses_xytheta = np.array(array, dtype=np.float64)

    def _call(self, header: dict[str, Any], arrays: Sequence[np.ndarray[Any, Any]]) -> None:
        answer, received = self._worker.request(header, arrays, str(header["op"]))
        self._take(answer, received)

    def predict(self, d: float, alpha: float, dt: float | None = None) -> None:
        self._call({"op": "predict", "d": float(d), "alpha": float(alpha),
                    "dt": None if dt is None else float(dt),
                    "dt_arg": self.capabilities.takes_dt}, [])  # fmt: skip

    def update(self, ids: IntArray, z: FloatArray) -> None:
        self._call({"op": "update"}, [np.asarray(ids, dtype=np.int64),
                                      np.asarray(z, dtype=np.float64)])  # fmt: skip

    def remove_landmarks(self, ids: Sequence[int]) -> None:
        self._call({"op": "remove_landmarks", "ids": [int(i) for i in ids]}, [])

    def finish(self) -> None:
        self._call({"op": "finish"}, [])

    def close(self) -> None:
        self._worker.close()


@dataclass(frozen=True, slots=True)
class StartedWorker:
    """A worker started ahead of the module it is to import, and the private copy of the
    submission it is shown (:class:`PrivateCopy`'s, refreshed by its owner)."""

    process: WorkerProcess
    mounts: tuple[bwrap.Mount, ...]


class WorkerFactory:
    """``make_filter(params)`` for a user's filter: a :class:`RemoteFilter` in a new worker.

    The first worker is started (and the module imported) at once, so that a module that
    cannot load fails before any work; the first construction takes it.

    :param started: a worker already started to import the module into first; the
        later ones are shown its private copy too (its owner's to remove)
    """

    def __init__(
        self,
        target: Target,
        options: WorkerOptions,
        label: str,
        started: StartedWorker | None = None,
    ) -> None:
        self.target = target
        self.options = options
        self.label = label
        self.mounts = _private_copy(target, options) if started is None else started.mounts
        owned = self.mounts if started is None else ()
        self._removal = weakref.finalize(self, _remove_copies, owned)
        self._made: list[LoadedWorker] = []  # the workers of the filters made, to end them
        process = None if started is None else started.process
        try:
            self._spare: LoadedWorker | None = LoadedWorker(
                target, options, label, self.mounts, process
            )
        except BaseException:
            self._removal()
            raise
        self.style = self._spare.style

    def __call__(self, params: FilterParams) -> RemoteFilter:
        loaded, self._spare = self._spare, None
        if loaded is None or loaded.process.process.poll() is not None:
            loaded = LoadedWorker(self.target, self.options, self.label, self.mounts)
        self._made.append(loaded)
        return RemoteFilter(loaded, params)

    def close(self) -> None:
        """End every worker started: the spare and those of the filters made. Each ends
        with its output echoed to the last line, so that nothing the filter printed comes
        after the line the command then says (its verdict or its error)."""
        if self._spare is not None:
            self._spare.process.close()
            self._spare = None
        for loaded in self._made:
            loaded.process.close()
        self._made.clear()
        self._removal()


def submission_of(target: Target, options: WorkerOptions) -> Submission | None:
    """What of the caller's files the sandbox shows the worker: the options' choice
    (``grade``: the submission), else the target's, else a file's folder (its Python
    files); None: nothing."""
    if options.submission is not None:
        return options.submission
    if target.submission is not None:
        return target.submission
    if target.path is not None:
        return Submission(os.path.dirname(os.path.abspath(target.path)), python_only=True)
    return None


class PrivateCopy:
    """A submission's private copy kept at one folder and made again before each run:
    what workers started ahead of their run are shown (``ekfviz watch``, where the
    submission changes between runs). Nothing without the sandbox.
    """

    def __init__(self, target: Target, options: WorkerOptions) -> None:
        self._submission = submission_of(target, options) if options.sandbox else None
        self.mounts: tuple[bwrap.Mount, ...] = ()
        if self._submission is not None:
            folder = private_folder()
            self.mounts = (bwrap.Mount(folder, self._submission.root),)
        self._removal = weakref.finalize(self, _remove_copies, self.mounts)

    def refresh(self) -> None:
        """Copy the submission again, as it is now, into the same folder.

        :raises WorkerFault: the submission is not copied (kind ``refused``)
        """
        if self._submission is None:
            return
        try:
            copy(self._submission, survey(self._submission), into=self.mounts[0].source)
        except SubmissionRefused as error:
            raise WorkerFault(printable(str(error)), "refused") from None
        except OSError as error:  # (ekfviz's side: its temporary folder)
            raise WorkerFault(f"the submission could not be copied: {error}", "start") from None

    def close(self) -> None:
        """Remove the copy."""
        self._removal()


def _private_copy(target: Target, options: WorkerOptions) -> tuple[bwrap.Mount, ...]:
    """The private copy of the submission a sandboxed worker sees, as its mount (none
    without the sandbox).

    :raises WorkerFault: the submission is not copied (kind ``refused``)
    """
    submission = submission_of(target, options) if options.sandbox else None
    if submission is None:
        return ()
    try:
        folder = copy(submission, survey(submission))
    except SubmissionRefused as error:
        raise WorkerFault(printable(str(error)), "refused") from None
    except OSError as error:  # (ekfviz's side: its temporary folder)
        raise WorkerFault(f"the submission could not be copied: {error}", "start") from None
    return (bwrap.Mount(folder, submission.root),)


def _remove_copies(mounts: Sequence[bwrap.Mount]) -> None:
    for mount in mounts:
        remove(mount.source)
