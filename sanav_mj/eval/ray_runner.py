"""Run a campaign's jobs on Ray: a local Ray, or an existing cluster of many machines.

:class:`RayExecutor` plugs into :func:`sanav_mj.eval.campaign.run_jobs` in place of the
process pool; everything else (the lazy jobs, the journal written on the driver as each task
finishes, ``--resume``, error rows, Ctrl-C) is the campaign's own, so a campaign gives the
same rows on Ray as on the pool.

- **Bounded work in flight.** At most ``2 x`` the cluster's CPUs tasks are submitted at a
  time (``ray.wait`` returns each as it finishes); a campaign of any size holds no more
  futures than that.
- **Files travel with the tasks.** A cluster node does not have the user's files: the driver
  resolves each scenario and reads it with every file it refers to (``<include>``\\s, meshes,
  textures, height fields), keeping their layout relative to the scenario's folder
  (:func:`scenario_bundle`). The bundle is put once in Ray's object store; a worker writes it
  into a temporary folder the first time it meets it and runs from there. The run JSON
  names the scenario by its file stem, as on the driver. A recording (``rrd``) is written
  on the worker into a temporary file and its bytes are sent back to the driver, which
  writes them at the job's path.
- **The solver** is compiled once per node into its cache (``~/.cache/sanav-mj`` or
  ``$SANAV_MJ_CACHE``; written under a temporary name and renamed, so concurrent workers
  on a node never load a half-written library).
- **Ray is optional** (``pip install -e ".[cluster]"``): without it :func:`ray_session`
  raises :class:`ClusterError` saying how to install it.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import re
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from sanav_mj.eval.campaign import ClusterError, Executor, Job, error_row, run_job

#: how to get Ray, said when it is missing
INSTALL_HINT = 'python -m pip install -e ".[cluster]" (or: python -m pip install "ray[client]==2.60.0")'
#: tasks in flight per CPU of the cluster
IN_FLIGHT_PER_CPU = 2


# --------------------------------------------------------------------------- what travels with a task

@dataclass(frozen=True)
class ScenarioBundle:
    """A scenario file with every file it refers to, ready to travel to another machine.

    Attributes:
        main: path of the scenario file inside the bundle (relative, ``/``-separated).
        files: ``(relative path, bytes)`` of every file, the scenario's included.
        digest: sha256 of the contents and layout (names the bundle's folder on a worker).
    """

    main: str
    files: tuple[tuple[str, bytes], ...]
    digest: str


_ASSET_TAGS = {"mesh": "meshdir", "skin": "meshdir", "texture": "texturedir", "hfield": "assetdir"}


def _referenced(path: Path, root_dir: Path, dirs: dict[str, str], seen: set[Path]) -> list[tuple[Path, str, str]]:
    """Files an MJCF file refers to, recursively: ``(resolved path, tag, attribute value)``.

    MuJoCo resolves ``<include file>`` and asset files against the main file's folder
    (assets also under the compiler's ``meshdir`` / ``texturedir`` / ``assetdir``).
    """
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError):
        return []  # not XML (a mesh): nothing inside it refers to files
    for comp in root.iter("compiler"):
        for attr in ("meshdir", "texturedir", "assetdir"):
            if comp.get(attr):
                dirs[attr] = comp.get(attr)
    out: list[tuple[Path, str, str]] = []
    for el in root.iter():
        value = el.get("file")
        if not value or el.tag not in ("include", "model", *_ASSET_TAGS):
            continue
        candidates = [Path(value)] if os.path.isabs(value) else (
            [root_dir / value] if el.tag in ("include", "model") else
            [root_dir / dirs.get(_ASSET_TAGS[el.tag], dirs.get("assetdir", "")) / value, root_dir / value])
        found = next((c.resolve() for c in candidates if c.is_file()), None)
        if found is None or found in seen:
            continue  # missing (e.g. the packaged robot, supplied on the worker as on the driver) or seen
        seen.add(found)
        out.append((found, el.tag, value))
        if el.tag in ("include", "model"):
            out.extend(_referenced(found, root_dir, dirs, seen))
    return out


def scenario_bundle(spec: str | Path) -> ScenarioBundle:
    """Read the scenario ``spec`` (path or built-in name) with every file it refers to.

    Files keep their layout relative to the scenario's folder (the common folder of all of
    them is the bundle's root), so relative ``<include file="../models/robot.xml"/>`` work
    unchanged; a reference by absolute path is rewritten, in the copy that travels, to the
    file's relative place in the bundle.

    Raises:
        sanav_mj.scene.ScenarioError: ``spec`` names no scenario file.
    """
    from sanav_mj.scene import resolve_scenario_path

    main = resolve_scenario_path(spec)
    refs = _referenced(main, main.parent, {}, {main})
    paths = [main] + [p for p, _, _ in refs]
    root = Path(os.path.commonpath([str(p.parent) for p in paths]))
    contents = {p: p.read_bytes() for p in paths}
    absolute = [(p, value) for p, _, value in refs if os.path.isabs(value)]
    if absolute:  # point them at their place in the bundle, relative to the main file's folder
        for p in paths:
            if p.suffix.lower() != ".xml":
                continue
            text = contents[p].decode("utf-8", errors="surrogateescape")
            for target, value in absolute:
                rel = os.path.relpath(target, main.parent).replace(os.sep, "/")
                pattern = r'(file\s*=\s*)(["\'])' + re.escape(value) + r"\2"
                text = re.sub(pattern, lambda m, rel=rel: f'{m.group(1)}"{rel}"', text)
            contents[p] = text.encode("utf-8", errors="surrogateescape")
    files = tuple(sorted((p.relative_to(root).as_posix(), data) for p, data in contents.items()))
    h = hashlib.sha256()
    for name, data in files:
        h.update(name.encode() + b"\0" + hashlib.sha256(data).digest())
    return ScenarioBundle(main.relative_to(root).as_posix(), files, h.hexdigest()[:24])


_UNPACKED: dict[str, Path] = {}


def unpack(bundle: ScenarioBundle) -> Path:
    """Write ``bundle`` into a temporary folder of this process (once per bundle); the path of
    its scenario file there."""
    folder = _UNPACKED.get(bundle.digest)
    if folder is None:
        folder = Path(tempfile.mkdtemp(prefix=f"sanav-mj-{bundle.digest[:8]}-"))
        for name, data in bundle.files:
            target = folder / name
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(data)
        _UNPACKED[bundle.digest] = folder
    return folder / bundle.main


def run_shipped(job: Job, bundle: ScenarioBundle, runner: Callable[[Job], dict[str, Any]] | None = None
                ) -> tuple[dict[str, Any], bytes | None]:
    """Run ``job`` on this machine from the shipped ``bundle`` of its scenario (the body of a
    Ray task).

    Returns:
        (the row, exactly as on the process pool: the run JSON without trace plus the tags,
        or :func:`~sanav_mj.eval.campaign.error_row` of ``job`` when the run raised; the
        bytes of the recording when ``job.rrd`` is set, else None).
    """
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    runner = run_job if runner is None else runner
    with tempfile.TemporaryDirectory(prefix="sanav-mj-rrd-") as tmp:
        rrd = Path(tmp) / "run.rrd" if job.rrd else None
        try:
            local = replace(job, scenario=str(unpack(bundle)), rrd=str(rrd) if rrd else None)
            row = runner(local)
        except Exception as exc:  # noqa: BLE001 - a failing run is a row, as on the pool
            return error_row(job, exc), None
        data = rrd.read_bytes() if rrd is not None and rrd.is_file() else None
    return row, data


# --------------------------------------------------------------------------- the session and the executor

def _import_ray():
    try:
        import ray
    except ImportError:
        raise ClusterError(f"--ray: Ray is not installed; install it with {INSTALL_HINT}") from None
    return ray


@dataclass
class RaySession:
    """A connection to Ray made by :func:`ray_session`.

    Attributes:
        address: what was asked for (None: a local Ray started for this session).
        cpus: CPUs of the cluster when connected.
    """

    address: str | None
    cpus: int


@contextlib.contextmanager
def ray_session(address: str | None = None, num_cpus: int | None = None) -> Iterator[RaySession]:
    """Connect to Ray for the duration of a ``with`` block.

    Args:
        address: None or ``""``: start a local Ray (shut down at the end); ``"auto"``: the
            cluster this machine belongs to (``ray start`` ran here); ``"HOST:PORT"`` of a
            head node; ``"ray://HOST:PORT"``: Ray Client. When Ray is already initialised
            in this process, that connection is used and left open.
        num_cpus: CPUs of the local Ray (None: all of this machine's); ignored for a cluster.

    Raises:
        ClusterError: Ray is not installed, or the cluster cannot be reached (one line).
    """
    ray = _import_ray()
    started = False
    if not ray.is_initialized():
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                  "logging_level": logging.ERROR, "configure_logging": True}
        if address:
            kwargs["address"] = address
        else:  # a new local instance, even where a cluster runs (ray.init() alone would join that)
            kwargs.update(address="local", num_cpus=num_cpus)
        try:
            with _quiet_stderr():
                ray.init(**kwargs)
        except Exception as exc:  # noqa: BLE001 - Ray raises many kinds; the user needs one line
            message = " ".join(str(exc).split())[:300]
            where = f"--ray {address}" if address else "--ray"
            raise ClusterError(f"{where}: cannot start or reach Ray ({type(exc).__name__}: {message})") from None
        started = True
    try:
        cpus = int(ray.cluster_resources().get("CPU", 1))
        yield RaySession(address or None, max(cpus, 1))
    finally:
        if started:
            with _quiet_stderr():
                ray.shutdown()


@contextlib.contextmanager
def _quiet_stderr() -> Iterator[None]:
    """Send what Ray's start-up and shut-down print on file descriptor 2 to /dev/null: the
    command line's stderr holds one line at most."""
    try:
        saved = os.dup(2)
    except OSError:
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


class RayExecutor(Executor):
    """Runs the jobs of :func:`sanav_mj.eval.campaign.run_jobs` as Ray tasks.

    Each distinct scenario is bundled (:func:`scenario_bundle`) and put in the object store
    once; each task carries the job and a reference to its bundle. ``slots`` is
    :data:`IN_FLIGHT_PER_CPU` x the cluster's CPUs.

    Args:
        session: from :func:`ray_session`.
        runner: the function that runs one job (None: :func:`~sanav_mj.eval.campaign.run_job`).
        num_cpus: CPUs a task asks for (1: one run per CPU).
    """

    def __init__(self, session: RaySession, runner: Callable[[Job], dict[str, Any]] | None = None,
                 num_cpus: float = 1.0) -> None:
        self._ray = _import_ray()
        self._runner = runner
        self.slots = max(2, IN_FLIGHT_PER_CPU * session.cpus)
        self._task = self._ray.remote(num_cpus=num_cpus, max_retries=0)(run_shipped)
        self._bundles: dict[str, Any] = {}
        self._jobs: dict[Any, Job] = {}

    def _bundle(self, scenario: str) -> Any:
        ref = self._bundles.get(scenario)
        if ref is None:
            ref = self._bundles[scenario] = self._ray.put(scenario_bundle(scenario))
        return ref

    def submit(self, job: Job) -> Any:
        ref = self._task.remote(job, self._bundle(job.scenario), self._runner)
        self._jobs[ref] = job
        return ref

    def wait(self, handles: list[Any]) -> list[tuple[Any, dict[str, Any]]]:
        ray = self._ray
        ready, _ = ray.wait(handles, num_returns=1)
        more, _ = ray.wait(handles, num_returns=len(handles), timeout=0)
        out = []
        for ref in dict.fromkeys([*ready, *more]):
            job = self._jobs.pop(ref)
            try:
                row, rrd = ray.get(ref)
            except Exception as exc:  # noqa: BLE001 - a lost worker or node: a row, as on the pool
                cause = getattr(exc, "cause", None) or exc
                row, rrd = error_row(job, RuntimeError(f"a Ray task failed ({type(cause).__name__}: {cause})")), None
            if rrd is not None and job.rrd:
                _write_atomic(Path(job.rrd), rrd)
            out.append((ref, row))
        return out

    def stop(self) -> None:
        for ref in list(self._jobs):
            with contextlib.suppress(Exception):
                self._ray.cancel(ref, force=True)
        self._jobs.clear()


def _write_atomic(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


@contextlib.contextmanager
def campaign_executor(ray: str | bool | RaySession | None) -> Iterator[RayExecutor | None]:
    """The executor of a campaign for the ``ray`` argument of ``run_bench`` / ``run_robustness``.

    ``None`` / ``False``: None (the process pool); ``True`` or ``""``: a local Ray;
    an address string (``"auto"``, ``"HOST:PORT"``, ``"ray://HOST:PORT"``): that cluster;
    a :class:`RaySession`: that open session. A session started here is shut down at the end.

    Raises:
        ClusterError: Ray is not installed or the cluster cannot be reached.
    """
    if ray is None or ray is False:
        yield None
    elif isinstance(ray, RaySession):
        yield RayExecutor(ray)
    else:
        with ray_session(None if ray is True else (ray or None)) as session:
            yield RayExecutor(session)


def describe(ray: str | bool | RaySession | None) -> str | None:
    """How a campaign ran, for ``meta.json``: None (process pool), ``"ray"`` (local) or ``"ray ADDRESS"``."""
    if ray is None or ray is False:
        return None
    address = ray.address if isinstance(ray, RaySession) else (None if ray is True else ray or None)
    return f"ray {address}" if address else "ray"
