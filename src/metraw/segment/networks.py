"""Which network segments the cars: params.yaml ``training.model`` (``ModelSpec``), how it is built, what it
must do (the contract, checked on one dummy batch before any training) and what a checkpoint records of it.

Three kinds, one contract:
- ``{kind: metraw}`` (default): the compact U-Net of ``metraw.segment.model``, sized by the training profile
  (``base_channels``, ``depth``; FiLM conditioning with ``condition: true``);
- ``{kind: smp, arch: Unet, encoder: resnet18, encoder_weights: null, kwargs: {...}}``: any architecture and
  encoder that segmentation-models-pytorch builds (``smp.create_model``; ``pip install 'metraw[models]'``);
- ``{kind: python, factory: "my_model.py:build", kwargs: {...}}``: ``build(in_channels, out_channels, **kwargs)``
  in a file (relative to the working directory: the workflow folder) or an importable module
  (``"my_package.models:build"``), returning a ``torch.nn.Module``.

The contract (docs/training.md, "Your own model"): the network takes x of shape (B, in_channels, H, W), float32,
the packed CFA planes of the raw in variance-stabilised units (unit noise variance; ``in_channels`` = 4: a Bayer
cell's R, G, G, B sites in canonical order, a mono sensor's 2 x 2 cells alike), with H and W multiples of its
``multiple`` (metraw pads by reflection and crops back), and returns the logits of "car", shape
(B, out_channels, H, W) with ``out_channels`` = ``in_channels``: one logit per mosaic pixel. Only the metraw kind
takes the payload conditioning vector; another network is trained unconditioned (its record says so).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from metraw.errors import MetrawError

KINDS = ("metraw", "smp", "python")
#: Input side multiple of a python factory's network when neither ``pad_multiple`` nor the module's
#: ``input_multiple`` says: 2**5, what a 5-level encoder (ResNets, U-Nets of smp and TorchGeo) needs.
DEFAULT_MULTIPLE = 32
#: Side of the contract check's dummy input: the smallest multiple of the network's ``multiple`` at least this [px].
CHECK_SIDE_PX = 32
#: Keys of ``training.model`` per kind (``ModelSpec.from_dict``).
_KEYS = {"metraw": {"kind"},
         "smp": {"kind", "arch", "encoder", "encoder_weights", "kwargs", "pad_multiple"},
         "python": {"kind", "factory", "kwargs", "pad_multiple"}}


@dataclass(frozen=True)
class ModelSpec:
    """One entry of params.yaml ``training.model`` (see the module's docstring). ``pad_multiple``: the input side
    multiple the network needs (default: smp 2**encoder_depth, python the module's ``input_multiple`` or 32)."""

    kind: str = "metraw"
    arch: str | None = None
    encoder: str | None = None
    encoder_weights: str | None = None
    factory: str | None = None
    kwargs: dict[str, Any] = field(default_factory=dict)
    pad_multiple: int | None = None

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> "ModelSpec":
        """The spec of a ``training.model`` mapping (None: the default, metraw's U-Net); one-line errors."""
        if d is None:
            return cls()
        if not isinstance(d, dict):
            raise MetrawError(f"training.model must be a mapping with a kind ({', '.join(KINDS)}), got {d!r}")
        kind = d.get("kind", "metraw")
        if kind not in KINDS:
            raise MetrawError(f"training.model kind must be one of {', '.join(KINDS)}, got {kind!r}")
        unknown = set(d) - _KEYS[kind]
        if unknown:
            raise MetrawError(f"training.model of kind {kind} takes {', '.join(sorted(_KEYS[kind]))}; "
                              f"unknown: {', '.join(sorted(unknown))}")
        if kind == "smp" and not (isinstance(d.get("arch"), str) and isinstance(d.get("encoder"), str)):
            raise MetrawError("training.model of kind smp needs arch and encoder (smp's names, e.g. arch: Unet, "
                              "encoder: resnet18)")
        if kind == "python" and not (isinstance(d.get("factory"), str) and ":" in d["factory"]):
            raise MetrawError("training.model of kind python needs factory: 'FILE.py:FUNCTION' or 'MODULE:FUNCTION', "
                              f"got {d.get('factory')!r}")
        kwargs = d.get("kwargs") or {}
        if not isinstance(kwargs, dict):
            raise MetrawError(f"training.model kwargs must be a mapping, got {kwargs!r}")
        multiple = d.get("pad_multiple")
        if multiple is not None and not (isinstance(multiple, int) and not isinstance(multiple, bool) and multiple >= 1):
            raise MetrawError(f"training.model pad_multiple must be a positive integer, got {multiple!r}")
        return cls(kind, d.get("arch"), d.get("encoder"), d.get("encoder_weights"), d.get("factory"), dict(kwargs),
                   multiple)

    def to_dict(self) -> dict[str, Any]:
        """The ``training.model`` mapping of this spec: its kind's keys, ``kwargs`` and ``pad_multiple`` when set."""
        out: dict[str, Any] = {"kind": self.kind}
        if self.kind == "smp":
            out.update(arch=self.arch, encoder=self.encoder, encoder_weights=self.encoder_weights)
        elif self.kind == "python":
            out["factory"] = self.factory
        if self.kwargs:
            out["kwargs"] = self.kwargs
        if self.pad_multiple is not None:
            out["pad_multiple"] = self.pad_multiple
        return out

    def identity(self) -> tuple:
        """What makes two specs build the same network: kind, smp names, the factory (its resolved file, or the
        module as written, and the function), kwargs and input multiple; a factory file's path as written does not
        count (a checkpoint records it resolved)."""
        factory = None
        if self.kind == "python":
            target, name = self.factory.rsplit(":", 1)
            factory = (str(self.factory_file() or target), name)
        return (self.kind, self.arch, self.encoder, self.encoder_weights, factory,
                json.dumps(self.kwargs, sort_keys=True), self.pad_multiple)

    def describe(self) -> str:
        """A short name: "metraw U-Net", "smp Unet (resnet18)", "python my_model.py:build"."""
        if self.kind == "smp":
            return f"smp {self.arch} ({self.encoder})"
        if self.kind == "python":
            return f"python {self.factory}"
        return "metraw U-Net"

    # ------------------------------------------------------------------ a python factory
    def factory_file(self, base_dir: str | Path | None = None) -> Path | None:
        """The factory's file (a ``.py`` before the colon, relative to ``base_dir``, default the working directory),
        resolved; None for a module name or another kind."""
        if self.kind != "python":
            return None
        target = self.factory.rsplit(":", 1)[0]
        if not target.endswith(".py"):
            return None
        path = Path(target)
        return (path if path.is_absolute() else Path(base_dir or ".") / path).resolve()


def model_spec(training: dict[str, Any] | None) -> ModelSpec:
    """The spec of a params ``training:`` section (its ``model``; the default when absent)."""
    return ModelSpec.from_dict((training or {}).get("model"))


def file_sha256(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _load_factory(spec: ModelSpec, base_dir=None):
    """The factory function of a python spec; one-line errors for a missing file or module, a module that fails
    to import, a missing or non-callable function."""
    target, name = spec.factory.rsplit(":", 1)
    where = f"training.model factory {spec.factory!r}"
    path = spec.factory_file(base_dir)
    try:
        if path is not None:
            if not path.is_file():
                raise MetrawError(f"{where}: no file {path}")
            module_name = f"metraw_user_model_{hashlib.sha256(str(path).encode()).hexdigest()[:12]}"
            loader_spec = importlib.util.spec_from_file_location(module_name, path)
            module = importlib.util.module_from_spec(loader_spec)
            sys.modules[module_name] = module  # dataclasses and pickling look the module up by name
            try:
                loader_spec.loader.exec_module(module)
            except BaseException:
                sys.modules.pop(module_name, None)
                raise
        else:
            try:
                module = importlib.import_module(target)
            except ModuleNotFoundError as exc:
                if exc.name and target.startswith(exc.name):
                    raise MetrawError(f"{where}: no module {target!r} (a file needs its .py suffix)") from None
                raise
    except MetrawError:
        raise
    except Exception as exc:
        raise MetrawError(f"{where}: importing it raised {type(exc).__name__}: {_one_line(exc)}") from None
    function = getattr(module, name, None)
    if function is None:
        raise MetrawError(f"{where}: {path or target} defines no {name!r}")
    if not callable(function):
        raise MetrawError(f"{where}: {name!r} is not a function")
    return function


def _one_line(exc: BaseException, limit: int = 200) -> str:
    return " ".join(str(exc).split())[:limit]


def build_core(spec: ModelSpec, in_channels: int, out_channels: int, base_dir=None):
    """(network, input side multiple) of a smp or python spec, freshly initialised (torch's global generator:
    seed it first). One-line errors for what cannot be built."""
    import torch

    where = f"training.model {spec.describe()}"
    if spec.kind == "smp":
        try:
            import segmentation_models_pytorch as smp
        except Exception as exc:  # not installed, or a torchvision that does not fit the installed torch
            raise MetrawError(f"{where} needs segmentation-models-pytorch ({_one_line(exc)}): "
                              "pip install 'metraw[models]'") from None
        archs = sorted(cls.__name__ for cls in (getattr(smp, "MODEL_ARCHITECTURES_MAPPING", None) or {}).values())
        if archs and spec.arch.lower() not in {a.lower() for a in archs}:
            raise MetrawError(f"{where}: smp has no architecture {spec.arch!r} (have {', '.join(archs)})")
        try:
            network = smp.create_model(spec.arch, encoder_name=spec.encoder, encoder_weights=spec.encoder_weights,
                                       in_channels=in_channels, classes=out_channels, **spec.kwargs)
        except Exception as exc:
            raise MetrawError(f"{where}: smp could not build it: {type(exc).__name__}: {_one_line(exc)}") from None
        multiple = spec.pad_multiple or 2 ** int(spec.kwargs.get("encoder_depth", 5))
    else:
        build = _load_factory(spec, base_dir)
        try:
            network = build(in_channels, out_channels, **spec.kwargs)
        except Exception as exc:
            raise MetrawError(f"{where}: build({in_channels}, {out_channels}, **kwargs) raised "
                              f"{type(exc).__name__}: {_one_line(exc)}") from None
        if not isinstance(network, torch.nn.Module):
            raise MetrawError(f"{where}: build returned a {type(network).__name__}, not a torch.nn.Module")
        multiple = spec.pad_multiple or int(getattr(network, "input_multiple", DEFAULT_MULTIPLE))
    return network, multiple


def check_contract(model, spec: ModelSpec, in_channels: int = 4) -> None:
    """Run ``model`` (a ``metraw.segment.model`` wrapper) once on a dummy batch (2, in_channels, H, W) at the
    multiple of its network, in eval mode without gradients (no weight, running statistic or global random state
    changes), and check that it returns finite logits of the input's shape; else one line naming the model."""
    import torch

    where = f"training.model {spec.describe()}"
    core, multiple = model.core, model.multiple
    side = multiple * math.ceil(CHECK_SIDE_PX / multiple)
    generator = torch.Generator().manual_seed(0)
    x = torch.randn(2, in_channels, side, 2 * side, generator=generator)
    device = next((p.device for p in core.parameters()), torch.device("cpu"))
    x = x.to(device)
    args = (x, torch.zeros(2, model.n_condition, device=device)) if model.n_condition else (x,)  # FiLM's payload
    was_training = core.training
    core.eval()
    try:
        with torch.no_grad():
            y = core(*args)
    except Exception as exc:
        raise MetrawError(f"{where}: its forward pass on a ({', '.join(map(str, x.shape))}) batch raised "
                          f"{type(exc).__name__}: {_one_line(exc)}") from None
    finally:
        core.train(was_training)
    if not isinstance(y, torch.Tensor):
        raise MetrawError(f"{where}: returns a {type(y).__name__}, not a tensor of logits")
    if tuple(y.shape) != tuple(x.shape):
        raise MetrawError(f"{where}: returns logits of shape {tuple(y.shape)} for an input of {tuple(x.shape)}; "
                          f"metraw needs {tuple(x.shape)}: one logit per packed CFA site (out_channels = in_channels)")
    if not bool(torch.isfinite(y).all()):
        raise MetrawError(f"{where}: returns non-finite logits (NaN or inf) on a finite input")


def network_record(model, spec: ModelSpec, base_dir=None) -> dict[str, Any]:
    """What a checkpoint records of its network: the spec, the factory file (resolved) and its sha256, the
    parameter count, whether it takes the payload conditioning, the input side multiple."""
    path = spec.factory_file(base_dir)
    return {**spec.to_dict(), "name": spec.describe(),
            "factory_file": None if path is None else str(path),
            "factory_sha256": None if path is None else file_sha256(path),
            "parameters": int(sum(p.numel() for p in model.parameters())),
            "conditioned": bool(getattr(model, "n_condition", 0)), "multiple": int(model.multiple)}


def spec_from_record(record: dict[str, Any] | None) -> ModelSpec:
    """The spec a checkpoint's network record was built from (None: a checkpoint of metraw's U-Net written before
    networks were recorded). A python factory given by file is taken from the recorded absolute path where that
    file is, else as written (relative to the working directory: a moved workflow folder)."""
    if not record:
        return ModelSpec()
    spec = ModelSpec.from_dict({k: record[k] for k in _KEYS[record.get("kind", "metraw")] if k in record})
    if record.get("factory_file") and Path(record["factory_file"]).is_file():
        spec = ModelSpec(spec.kind, factory=f"{record['factory_file']}:{spec.factory.rsplit(':', 1)[1]}",
                         kwargs=spec.kwargs, pad_multiple=spec.pad_multiple)
    return spec


def check_rebuilt(record: dict[str, Any], spec: ModelSpec, model) -> None:
    """A network rebuilt from a checkpoint's ``record`` (by ``spec_from_record``'s ``spec``) is the one that was
    trained: the factory file's sha256 and the parameter count agree, else one line."""
    path = spec.factory_file()
    if record.get("factory_sha256") and path is not None:
        now = file_sha256(path)
        if now != record["factory_sha256"]:
            raise MetrawError(f"its factory file {path} changed since the training "
                              f"(sha256 {now[:12]} against {record['factory_sha256'][:12]}): restore it or train again")
    n = int(sum(p.numel() for p in model.parameters()))
    if record.get("parameters") is not None and n != record["parameters"]:
        raise MetrawError(f"{record.get('name')} now builds {n} parameters, the checkpoint holds "
                          f"{record['parameters']}: its factory or kwargs changed; train again")


def factory_files(training: dict[str, Any] | None, where: str = "params") -> list[str]:
    """The python factory files a ``training:`` section's networks are built from (``model`` and the profiles'
    own), as written (relative to the workflow folder): a workflow's rules take them as inputs, so editing one
    reruns the trainings. A quick check without importing them or torch: a missing file, a syntax error or no
    top-level ``FUNCTION`` is one line (the contract itself is checked by each training, ``check_contract``)."""
    import ast

    training = training or {}
    specs = [training.get("model")] + [p.get("model") for p in (training.get("profiles") or {}).values()
                                       if isinstance(p, dict)]
    files = []
    for d in specs:
        spec = ModelSpec.from_dict(d) if d is not None else None
        path = spec.factory_file() if spec is not None else None
        if path is None:
            continue
        prefix = f"{where}: training.model factory {spec.factory!r}"
        if not path.is_file():
            raise MetrawError(f"{prefix}: no file {path}")
        try:
            tree = ast.parse(path.read_bytes(), str(path))
        except SyntaxError as exc:
            raise MetrawError(f"{prefix}: {path.name} line {exc.lineno}: {exc.msg}") from None
        name = spec.factory.rsplit(":", 1)[1]
        defined = {n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))}
        defined |= {t.id for n in tree.body if isinstance(n, ast.Assign) for t in n.targets if isinstance(t, ast.Name)}
        defined |= {(a.asname or a.name) for n in tree.body if isinstance(n, ast.ImportFrom) for a in n.names}
        if name not in defined:
            raise MetrawError(f"{prefix}: {path.name} defines no {name!r}")
        relative = spec.factory.rsplit(":", 1)[0]
        if relative not in files:
            files.append(relative)
    return files
