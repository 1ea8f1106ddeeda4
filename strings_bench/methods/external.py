"""Method "external": wrap any program that trains on a scene folder and writes test-view renders.

This is the documented example of an adapter for code that lives outside this package (another
repository, another Python environment, a binary). For each checkpoint the runner asks for, the
adapter runs a command built from a template and reads the PNG renders it wrote.

Settings:

- `command` (required): a command template. Placeholders: `{scene}` (scene folder), `{out}` (an
  empty folder for this checkpoint's renders), `{iteration}` (the checkpoint iteration),
  `{downscale}`, `{test_views}` (comma-separated test image names), `{name}` (scene name). Values
  are shell-quoted; the command runs without a shell unless `shell` is true.
- `shell` (default false), `timeout` (seconds per command, default none), `workdir` (where renders
  go; default a temporary folder that is removed afterwards), `env` (extra environment variables).

Contract with the command: write one PNG per test view into `{out}`, named after the test image
(`<image stem>.png`, or the image's own name if it ends in .png), at the size of the scene's images
for the downscale; optionally `{out}/stats.json` with `train_seconds`, `gaussians` and
`preprocess_seconds` (default 0). Without stats.json, training time is the command's wall time and
Gaussians are unknown (n/a).

The command is run once per checkpoint; a program that trains progressively can keep its own state
between calls (e.g. resume from its checkpoint at the previous iteration).

    strings-bench run --methods external \\
        --set 'external.command=python train.py -s {scene} --iterations {iteration} --render-test-to {out}'
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Iterator

import numpy as np
from PIL import Image

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.method import CheckpointResult, MethodAdapter
from strings_bench.core.settings import Setting

PLACEHOLDERS = ("scene", "out", "iteration", "downscale", "test_views", "name")


class ExternalCommandAdapter(MethodAdapter):
    name = "external"

    @classmethod
    def settings_schema(cls) -> list[Setting]:
        g = "external"
        return [Setting("command", None, "command template: {scene} {out} {iteration} {downscale} {test_views} {name}", g),
                Setting("shell", False, "run the command through a shell", g),
                Setting("timeout", None, "seconds per command (None: no limit)", g),
                Setting("workdir", None, "where renders go (None: a temporary folder, removed afterwards)", g),
                Setting("env", None, "extra environment variables (a JSON object)", g)]

    def build_command(self, scene, out: Path, iteration: int, downscale: float) -> list[str] | str:
        template = self.settings.get("command")
        if not template:
            raise StringsBenchError("method external needs the setting command",
                                    hint="e.g. --set 'external.command=my_trainer {scene} {out} {iteration}'")
        values = {"scene": str(scene.root), "out": str(out), "iteration": str(iteration), "downscale": f"{downscale:g}",
                  "test_views": ",".join(scene.names[i] for i in scene.test_idx), "name": scene.name}
        quoted = {k: shlex.quote(v) for k, v in values.items()}
        try:
            text = str(template).format(**quoted)
        except (KeyError, IndexError) as exc:
            raise StringsBenchError(f"command template {template!r} has an unknown placeholder {exc}",
                                    hint=f"placeholders: {', '.join('{' + p + '}' for p in PLACEHOLDERS)}") from exc
        return text if self.settings.get("shell") else shlex.split(text)

    def _run(self, cmd, iteration: int, scene) -> float:
        env = dict(os.environ)
        env.update({str(k): str(v) for k, v in (self.settings.get("env") or {}).items()})
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(cmd, shell=bool(self.settings.get("shell")), capture_output=True, text=True,
                                  timeout=self.settings.get("timeout"), env=env)
        except FileNotFoundError as exc:
            raise StringsBenchError(f"external method: cannot start {cmd if isinstance(cmd, str) else cmd[0]!r}: {exc}",
                                    hint="check the command setting (is the program on PATH?)") from exc
        except subprocess.TimeoutExpired as exc:
            raise StringsBenchError(f"external method: command timed out after {exc.timeout} s at iteration {iteration} "
                                    f"on {scene.name}", hint="raise the timeout setting") from exc
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout or "").strip()[-1500:]
            shown = cmd if isinstance(cmd, str) else shlex.join(cmd)
            raise StringsBenchError(
                f"external method: command failed with exit code {proc.returncode} at iteration {iteration} on "
                f"{scene.name}: {shown}\n{tail}", hint="run the command by hand to see what went wrong")
        return time.perf_counter() - t0

    def read_renders(self, scene, out: Path, downscale: float) -> dict[str, np.ndarray]:
        renders, missing = {}, []
        for i in scene.test_idx:
            name = scene.names[i]
            candidates = [out / f"{Path(name).stem}.png", out / name]
            path = next((p for p in candidates if p.is_file() and p.suffix.lower() == ".png"), None)
            if path is None:
                missing.append(f"{Path(name).stem}.png")
                continue
            cam = scene.camera(i, downscale)
            with Image.open(path) as im:
                if im.size != (cam.width, cam.height):
                    raise StringsBenchError(
                        f"external method: render {path} is {im.size[0]}x{im.size[1]}, expected {cam.width}x{cam.height} "
                        f"(scene {scene.name}, downscale {downscale:g})",
                        hint="render test views at the scene's image size divided by the downscale")
                renders[name] = np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
        if missing:
            found = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
            raise StringsBenchError(
                f"external method: the command wrote no render for {len(missing)} test view(s) of {scene.name} in {out}: "
                f"{', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''} (found: {', '.join(found[:5]) or 'nothing'})",
                hint="write one PNG per test view, named <image stem>.png, into {out}")
        return renders

    def train(self, scene, checkpoints: list[int], downscale: float = 1) -> Iterator[CheckpointResult]:
        workdir = self.settings.get("workdir")
        tmp = None
        if workdir is None:
            tmp = tempfile.TemporaryDirectory(prefix="strings-bench-external-")
            workdir = tmp.name
        total = 0.0
        try:
            for it in sorted(checkpoints):
                out = Path(workdir) / scene.name / str(it)
                out.mkdir(parents=True, exist_ok=True)
                total += self._run(self.build_command(scene, out, it, downscale), it, scene)
                renders = self.read_renders(scene, out, downscale)
                stats = {}
                if (out / "stats.json").is_file():
                    try:
                        stats = json.loads((out / "stats.json").read_text())
                    except ValueError as exc:
                        raise StringsBenchError(f"external method: {out / 'stats.json'} is not JSON: {exc}",
                                                hint='write {"train_seconds": ..., "gaussians": ...}') from exc
                yield CheckpointResult(
                    iteration=it, renders=renders,
                    train_seconds=float(stats.get("train_seconds", total)),
                    gaussians=int(stats.get("gaussians", -1)),  # -1: unknown, shown as n/a
                    extra={"command_seconds": total, "stats": stats},
                    preprocess_seconds=float(stats.get("preprocess_seconds", 0.0)),
                )
        finally:
            if tmp is not None:
                tmp.cleanup()
