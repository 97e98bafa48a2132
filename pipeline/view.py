"""Open a Rerun recording (``.rrd``) in the viewer, or render it to a PNG without a screen.

Both use the ``rerun`` binary that ships inside the installed rerun-sdk wheel
(:func:`sinks.rerun_tools.rerun_cli`), so the viewer always matches the SDK that wrote the file.

* :func:`open_viewer` runs ``rerun FILE.rrd`` (a window; needs a display), or serves the web
  viewer on 127.0.0.1 with ``web=True``.
* :func:`screenshot` starts the viewer headless (``rerun --headless``, rendering offscreen with
  whatever Vulkan/GL adapter the machine has; on a server without a GPU that is Mesa's software
  rasterizer, Debian package ``mesa-vulkan-drivers``), loads the file, puts the time cursor on a
  frame (``--frame``, default: the last one), waits for the load to finish and saves a PNG of the
  whole viewer through the viewer's control API (``rerun.experimental.ViewerClient``).  The
  viewer listens on a free port of 127.0.0.1 only and is stopped afterwards.

Subprocesses run with :func:`sinks.rerun_tools.rerun_env`: the CLI's analytics off (``CI`` set)
and its log quiet, except the interactive viewer of :func:`open_viewer`, which keeps the user's
own ``rerun analytics`` choice.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from bnptrack.pipeline.ports import free_port


__all__ = ["ViewerUnavailable", "viewer_failure", "open_viewer", "screenshot"]

#: What a machine without a usable renderer needs (Debian/Ubuntu).
RENDERER_HINT = (
    "the viewer needs a Vulkan or OpenGL adapter; on a machine without a GPU install Mesa's "
    "software renderer: `apt-get update && apt-get install -y mesa-vulkan-drivers`"
)


class ViewerUnavailable(RuntimeError):
    """The Rerun viewer cannot run here (no CLI, no display, or no renderer)."""


def _check_rrd(path: str | os.PathLike) -> Path:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(2, "No such file", str(path))
    return path


@contextlib.contextmanager
def _rrd_named(path: Path, folder: Path) -> Iterator[Path]:
    """``path`` under a name ending in ``.rrd`` (the viewer tells a recording by its suffix and
    waits on any other): ``path`` itself, else a link to it (a copy where links are not
    allowed) in ``folder``, removed on exit."""
    if path.suffix == ".rrd":
        yield path
        return
    named = folder / (path.name + ".rrd")
    try:
        named.symlink_to(path.resolve())
    except OSError:
        shutil.copyfile(path, named)
    try:
        yield named
    finally:
        named.unlink(missing_ok=True)


def open_viewer(path: str | os.PathLike, *, web: bool = False,
                extra_args: Sequence[str] = ()) -> int:
    """Open ``path`` in the Rerun viewer and wait until it is closed; returns its exit code.

    The viewer's own server listens on 127.0.0.1 only (``--bind 127.0.0.1``).  ``web=True``
    serves the web viewer instead (``rerun FILE --bind 127.0.0.1 --web-viewer``; open the
    printed URL in a browser).  Raises :class:`ViewerUnavailable` when there is no
    display for the native viewer (Linux without ``DISPLAY`` / ``WAYLAND_DISPLAY``).
    """
    from bnptrack.sinks.rerun_tools import rerun_cli, rerun_env

    path = _check_rrd(path)
    if not web and sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        raise ViewerUnavailable(
            "no display (neither DISPLAY nor WAYLAND_DISPLAY is set): use "
            "`bnptrack view FILE.rrd --screenshot OUT.png` to render it headless, or `--web` to "
            "serve the web viewer"
        )
    env = rerun_env(analytics=True, quiet=False)  # the user's own viewer, the user's settings
    with tempfile.TemporaryDirectory(prefix="bnptrack-view-") as tmp, _rrd_named(path, Path(tmp)) as named:
        cmd = [*rerun_cli(), str(named), "--bind", "127.0.0.1"]  # its server: this machine only
        cmd += ["--web-viewer"] if web else []
        cmd += list(extra_args)
        try:
            return subprocess.call(cmd, env=env)
        except OSError as exc:
            raise ViewerUnavailable(f"cannot run `{cmd[0]}`: {exc}") from exc


def _tail(path: Path, n: int = 2000) -> str:
    try:
        return path.read_text(errors="replace")[-n:].strip()
    except OSError:
        return ""


def viewer_failure(log: Path, why: str) -> ViewerUnavailable:
    """The :class:`ViewerUnavailable` for a viewer that failed (``why``), with what its log
    ``log`` says (the renderer hint when it is a missing renderer)."""
    out = _tail(log, 20000)
    lines = [ln.strip() for ln in out.splitlines()]
    key = [ln for ln in lines if ("panicked" in ln or "error" in ln.lower())
           and "XDG_RUNTIME_DIR" not in ln]
    said = "; ".join(key[:3]) or (lines[-1] if lines else "(no output)")
    if any(s in out.lower() for s in ("render context", "graphics adapter", "no suitable adapter")):
        return ViewerUnavailable(f"{why}: no renderer ({said}): {RENDERER_HINT}")
    return ViewerUnavailable(f"{why}: {said}. If this is a missing renderer: {RENDERER_HINT}")


def screenshot(
    path: str | os.PathLike,
    out_png: str | os.PathLike,
    frame: int | None = None,
    size: tuple[int, int] = (1600, 900),
    timeout: float = 60.0,
    *,
    timeline: str = "frame",
    view: str | None = None,
) -> Path:
    """Render ``path`` with the headless viewer at ``frame`` (default: the last) to ``out_png``.

    The picture is the recording's own default blueprint (scene and time series) at ``size``
    logical pixels, with the time cursor paused on ``frame`` of ``timeline``; ``view`` (the
    start of a view's name, e.g. ``"scene"``) captures that view alone.  Raises
    :class:`ViewerUnavailable` with the reason (e.g. no Vulkan/GL adapter: install
    ``mesa-vulkan-drivers``) when the viewer cannot start or render, :class:`ValueError` for a
    frame outside the recording or an ``out_png`` that is not a ``.png`` name, is the
    recording, or is an existing file other than a PNG (an existing PNG is replaced),
    :class:`TimeoutError` after ``timeout`` seconds.
    """
    given = _check_rrd(path)
    path = given.resolve()
    out_png = Path(out_png)
    _check_png_out(out_png, path)
    width, height = (int(v) for v in size)
    if width < 64 or height < 64:
        raise ValueError(f"size must be at least 64x64, got {width}x{height}")
    client_cls = _viewer_client_class()
    cli = _cli()
    deadline = time.monotonic() + timeout
    port = free_port()
    with tempfile.TemporaryDirectory(prefix="bnptrack-view-") as tmp, _rrd_named(path, Path(tmp)) as named:
        log = Path(tmp) / "viewer.log"
        proc = _start_headless(cli, port, (width, height), log)
        try:
            client = _connect(client_cls, proc, port, deadline, log)
            _call(lambda: client.open(str(named)), proc, deadline, log)
            state = _wait_loaded(client, proc, deadline, log, given)
            k = _pick_frame(state, path, timeline, frame)
            png = _capture(client, proc, deadline, log, timeline, k, lambda: _view_id(state, view))
            out_png.parent.mkdir(parents=True, exist_ok=True)
            out_png.write_bytes(png)
            return out_png
        finally:
            _stop(proc)


#: The bytes every PNG file starts with.
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _check_png_out(out_png: Path, recording: Path) -> None:
    """A screenshot goes to a ``.png`` file that is not the recording and, if it exists, is a
    PNG (a picture being regenerated); anything else is a :class:`ValueError` naming it."""
    if out_png.suffix.lower() != ".png":
        raise ValueError(f"--screenshot {out_png}: the picture is a PNG; give a file name ending in .png")
    if out_png.exists():
        if out_png.resolve() == recording:
            raise ValueError(f"--screenshot {out_png}: the picture would overwrite the recording it renders")
        with open(out_png, "rb") as f:
            if f.read(len(PNG_MAGIC)) != PNG_MAGIC:
                raise ValueError(f"--screenshot {out_png}: the file exists and is not a PNG; "
                                 f"choose another name or remove it")


def _viewer_client_class() -> Any:
    """``rerun.experimental.ViewerClient`` (rerun-sdk 0.41), else :class:`ViewerUnavailable`."""
    try:
        from rerun.experimental import ViewerClient
    except ImportError as exc:  # pragma: no cover - other rerun-sdk versions
        raise ViewerUnavailable(
            f"rerun.experimental.ViewerClient is not available in this rerun-sdk ({exc}); "
            "bnptrack needs rerun-sdk 0.41"
        ) from exc
    return ViewerClient


def _cli() -> list[str]:
    """The ``rerun`` command (:func:`sinks.rerun_tools.rerun_cli`), else :class:`ViewerUnavailable`."""
    from bnptrack.sinks.rerun_tools import RerunToolError, rerun_cli

    try:
        return rerun_cli()
    except RerunToolError as exc:
        raise ViewerUnavailable(str(exc)) from exc


def _start_headless(cli: list[str], port: int, size: tuple[int, int], log: Path) -> subprocess.Popen:
    """Start the headless viewer on 127.0.0.1:``port`` at ``size``, its output to ``log``."""
    from bnptrack.sinks.rerun_tools import rerun_env

    env = rerun_env()
    env["RERUN_APP_ONLY"] = "true"
    cmd = [*cli, "--headless", "--bind", "127.0.0.1", "--port", str(port),
           "--window-size", f"{size[0]}x{size[1]}", "--hide-welcome-screen",
           "--memory-limit", "2GB", "--server-memory-limit", "512MiB"]
    with open(log, "wb") as log_f:
        return subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log_f,
                                stderr=subprocess.STDOUT, env=env, start_new_session=True)


def _pick_frame(state: Any, path: Path, timeline: str, frame: int | None) -> int:
    """The time to show: ``frame`` (default: the last) on ``timeline`` of the active recording."""
    rec = next((r for r in state.recordings if r.store_id == state.active_recording),
               state.recordings[0] if state.recordings else None)
    if rec is None:
        raise ViewerUnavailable(f"the viewer opened no recording from {path}")
    tl = next((t for t in rec.timelines if t.name == timeline), None)
    if tl is None or tl.start is None or tl.end is None:
        names = ", ".join(t.name for t in rec.timelines) or "none"
        raise ValueError(f"{path} has no data on timeline {timeline!r} (timelines: {names})")
    k = tl.end if frame is None else int(frame)
    if not tl.start <= k <= tl.end:
        raise ValueError(f"frame {k} is outside the recording ({timeline} {tl.start}..{tl.end})")
    return k


def _view_id(state: Any, view: str | None) -> Any:
    """The id of the first view whose name starts with ``view`` (``None``: the whole window)."""
    if view is None:
        return None
    match = [v for v in state.views if v.name.startswith(view)]
    if not match:
        names = ", ".join(repr(v.name) for v in state.views)
        raise ValueError(f"no view named {view!r}... in the recording (views: {names})")
    return match[0].view_id


def _capture(client: Any, proc: subprocess.Popen, deadline: float, log: Path, timeline: str, k: int,
             pick_view: Callable[[], Any]) -> bytes:
    """The PNG of the view ``pick_view()`` gives (``None``: the whole window) with the time
    cursor paused at ``k``, without the top bar."""
    # no top bar in the picture: it carries the viewer's notices ("Software rasterizer",
    # the notification bell), not the recording
    _call(lambda: client.run_command("ui.toggle_top_panel"), proc, deadline, log)
    _call(lambda: client.set_time(timeline, sequence=k, play_state="paused"), proc, deadline, log)
    time.sleep(0.3)  # let the plots settle on the new cursor before painting
    view_id = pick_view()
    png = b""
    for _ in range(2):  # the second paint has the layout of the first
        png = _call(lambda: client.take_screenshot(view_id), proc, deadline, log)
    if not png.startswith(b"\x89PNG"):
        raise ViewerUnavailable("the viewer returned no PNG")
    return png


def _call(fn: Any, proc: subprocess.Popen, deadline: float, log: Path) -> Any:
    if proc.poll() is not None:
        raise viewer_failure(log, f"the headless viewer exited (code {proc.returncode})")
    if time.monotonic() > deadline:
        raise TimeoutError("the headless viewer did not answer in time")
    try:
        return fn()
    except (RuntimeError, OSError) as exc:
        try:  # a viewer that fails to start its renderer dies right after answering once
            proc.wait(timeout=3)
        except subprocess.TimeoutExpired:
            raise exc from None
        raise viewer_failure(log, f"the headless viewer exited (code {proc.returncode})") from exc


def _connect(client_cls: Any, proc: subprocess.Popen, port: int, deadline: float, log: Path) -> Any:
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    last: Exception | None = None
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise viewer_failure(log, f"the headless viewer exited at start (code {proc.returncode})")
        try:
            client = client_cls(url)
            client.get_state()
            return client
        except Exception as exc:  # not listening yet
            last = exc
            time.sleep(0.1)
    raise TimeoutError(f"the headless viewer did not start listening on {url}: {last}")


#: Seconds the viewer may load nothing and show no frame before a recording counts as holding none.
IDLE_EMPTY_S = 5.0


def _wait_loaded(client: Any, proc: subprocess.Popen, deadline: float, log: Path, path: Path) -> Any:
    """The viewer's state once the recording is loaded with its timelines; a :class:`ValueError`
    when the viewer loads nothing and shows no timeline for :data:`IDLE_EMPTY_S` seconds (a
    recording without frames, e.g. one repaired from its first bytes)."""
    idle_since = time.monotonic()
    while True:
        state = _call(client.get_state, proc, deadline, log)
        has_frames = bool(state.recordings) and bool(state.recordings[0].timelines)
        if not state.loading and has_frames:
            return state
        if state.loading or has_frames:
            idle_since = time.monotonic()
        elif time.monotonic() - idle_since > IDLE_EMPTY_S:
            raise ValueError(f"{path} holds no frames the viewer can show (a recording cut short before its "
                             f"first complete frame, or one with no frame data)")
        if time.monotonic() > deadline:
            raise TimeoutError("the headless viewer did not finish loading the recording in time")
        time.sleep(0.1)


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=10)
