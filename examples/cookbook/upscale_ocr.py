"""Cookbook: an OCR engine of your own (docs/cookbook/ocr-engine.md). `UpscaledRapidOCR` reads an image enlarged
`factor` times with RapidOCR and maps the boxes back: small text, as in low-resolution renders, is read by a
recogniser trained on larger text. Any engine is this much code: `_recognize(rgb) -> list[Word]`, a version, a
status.

Run it:  python examples/cookbook/upscale_ocr.py
"""

from __future__ import annotations

import numpy as np
from PIL import Image

from strings_bench.eval.ocr import BackendStatus, OCRBackend, Word, get_backend


class UpscaledRapidOCR(OCRBackend):
    """RapidOCR on the image enlarged `factor` times (Lanczos), boxes mapped back to the image's pixels."""

    name = "rapidocr-upscaled"

    def __init__(self, factor: int = 2, cache=None):
        super().__init__({"factor": int(factor)}, cache=cache)  # settings: all that changes the result
        self.inner = get_backend("rapidocr", cache=False)  # the engine it wraps; its own cache off

    @property
    def version(self) -> str:
        return f"upscaled-{self.inner.version}"

    @classmethod
    def status(cls) -> BackendStatus:
        inner = get_backend("rapidocr", cache=False).status()
        return BackendStatus(cls.name, inner.available, inner.detail)

    def _recognize(self, rgb: np.ndarray) -> list[Word]:
        f = self.settings["factor"]
        h, w = rgb.shape[:2]
        big = np.asarray(Image.fromarray(rgb).resize((w * f, h * f), Image.LANCZOS))
        return [Word(x.text, x.polygon / f, x.confidence) for x in self.inner.read(big)]


def main() -> None:
    from PIL import ImageDraw, ImageFont

    image = Image.new("RGB", (120, 30), "white")  # small text, about 7 px high
    ImageDraw.Draw(image).text((6, 10), "READ ME NOW", fill="black", font=ImageFont.load_default(size=9))
    rgb = np.asarray(image)
    for engine in (get_backend("rapidocr", cache=False), UpscaledRapidOCR(factor=3)):
        words = sorted(engine.read(rgb), key=lambda w: w.polygon[:, 0].min())  # left to right
        print(f"{engine.name:18s} read {' '.join(w.text for w in words) or '(nothing)'!r}")
    print(UpscaledRapidOCR(factor=3).describe()["settings"])


if __name__ == "__main__":
    main()
