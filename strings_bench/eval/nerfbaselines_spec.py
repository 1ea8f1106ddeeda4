"""Registers the `strings-ocr` evaluation protocol with nerfbaselines (loaded through its `nerfbaselines.specs`
entry points, declared in pyproject.toml; see eval/nerfbaselines_protocol.py)."""

from nerfbaselines import register

register({"id": "strings-ocr", "evaluation_protocol_class": "strings_bench.eval.nerfbaselines_protocol:StringsOCRProtocol"})
