"""The documentation site: MkDocs builds it in strict mode (a broken link, a missing page or a missing API object
fails), a planted dead link or missing object does fail it, and the landing page, a guide page and an API page
render in headless Chromium (not blank, their title, the navigation)."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from _browser import find_chromium

ROOT = Path(__file__).resolve().parents[2]
pytest.importorskip("mkdocs", reason="the docs extra is not installed (pip install -e '.[docs]')")
pytest.importorskip("mkdocstrings", reason="the docs extra is not installed (pip install -e '.[docs]')")

from strings_bench.cli.docs import build_site  # noqa: E402
from strings_bench.core.errors import StringsBenchError  # noqa: E402

# The built site's pages the browser test opens: page -> (its title, the start of its first heading).
PAGES = {
    "index.html": ("strings-bench", "Documentation"),
    "guide/getting-started.html": ("Getting started - strings-bench", "Getting started"),
    "reference/api.html": ("Python API - strings-bench", "Python API"),
}


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    start = time.perf_counter()
    build_site(ROOT, out)
    seconds = time.perf_counter() - start
    print(f"site built in {seconds:.1f} s")
    return out


def test_site_builds_in_strict_mode(site):
    for page in PAGES:
        assert (site / page).is_file(), page
    # every page of the navigation was built (a nav entry without its file is a strict-mode error as well)
    for page in ["guide/troubleshooting.html", "cookbook/index.html", "maintainers/gpu-campaign.html",
                 "changelog.html", "results/index.html"]:
        assert (site / page).is_file(), page


def test_api_reference_has_every_object(site):
    """Every object docs/reference/api.md names is rendered with its own heading (mkdocstrings' id is its path)."""
    from tests.docs.test_docs_api import api_objects

    html = (site / "reference" / "api.html").read_text(encoding="utf-8")
    missing = [obj for obj in api_objects() if f'id="{obj}"' not in html]
    assert not missing, missing


def _copy_checkout(tmp_path: Path) -> Path:
    """A checkout to plant faults in: mkdocs.yml and docs/ copied, the rest linked. The API page holds one object,
    so that the build is quick (the full page is built by the `site` fixture)."""
    root = tmp_path / "checkout"
    root.mkdir()
    shutil.copy(ROOT / "mkdocs.yml", root / "mkdocs.yml")
    shutil.copytree(ROOT / "docs", root / "docs", ignore=shutil.ignore_patterns("cells"))
    (root / "docs" / "reference" / "api.md").write_text("# Python API\n\n::: strings_bench.bench.run\n", encoding="utf-8")
    for name in ("strings_bench", "examples", "CHANGELOG.md", "README.md"):
        (root / name).symlink_to(ROOT / name)
    return root



def _build_fails(root: Path, capfd) -> str:
    with pytest.raises(StringsBenchError, match="did not build"):
        build_site(root, root / "site")
    out = capfd.readouterr()
    return out.out + out.err


def test_a_dead_link_or_a_missing_page_fails_the_build(tmp_path, capfd):
    """Both planted in one build (each a strict-mode warning, so MkDocs reports both before it stops)."""
    root = _copy_checkout(tmp_path)
    page = root / "docs" / "guide" / "running.md"
    page.write_text(page.read_text(encoding="utf-8") + "\nSee [the missing page](no-such-page.md).\n", encoding="utf-8")
    config = root / "mkdocs.yml"
    text = config.read_text(encoding="utf-8")
    assert "  - Troubleshooting: guide/troubleshooting.md\n" in text
    config.write_text(text.replace("  - Troubleshooting: guide/troubleshooting.md\n",
                                   "  - Troubleshooting: guide/troubleshooting.md\n  - Missing: guide/no-such-guide.md\n"),
                      encoding="utf-8")
    out = _build_fails(root, capfd)
    assert "no-such-page.md" in out and "no-such-guide.md" in out


def test_a_missing_api_object_fails_the_build(tmp_path, capfd):
    root = _copy_checkout(tmp_path)
    page = root / "docs" / "reference" / "api.md"
    page.write_text(page.read_text(encoding="utf-8") + "\n::: strings_bench.engine.splatting.NoSuchMethod\n",
                    encoding="utf-8")
    assert "NoSuchMethod" in _build_fails(root, capfd)


def test_docs_build_command(tmp_path):
    """`strings-bench docs build` is the command the README names; it prints where the site is."""
    done = subprocess.run([sys.executable, "-m", "strings_bench", "docs", "build", "--help"], cwd=ROOT,
                          capture_output=True, text=True)
    assert done.returncode == 0 and "--site-dir" in done.stdout
    assert "strings-bench docs build" in (ROOT / "README.md").read_text(encoding="utf-8")


# ---- the site in a real browser -----------------------------------------------------------------------------
def test_pages_render_in_headless_chromium(site, tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api", reason="Playwright's Python package is not installed")
    chromium = find_chromium()
    if chromium is None:
        pytest.skip("no chromium executable (/usr/bin/chromium; scripts/system_deps.sh installs Debian's)")
    import numpy as np
    from PIL import Image

    import functools
    import threading
    from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer

    # Served over HTTP as a reader's server would (the search index loads in a web worker, which file:// forbids).
    class Quiet(SimpleHTTPRequestHandler):
        def log_message(self, *args):  # no request log in the test's output
            pass

    handler = functools.partial(Quiet, directory=str(site))
    server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
    base = f"http://127.0.0.1:{server.server_address[1]}/"
    errors: list[str] = []
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.on("pageerror", lambda e: errors.append(f"{page.url}: {e}"))
            for rel, (title, heading) in PAGES.items():
                page.goto(base + rel)
                page.wait_for_load_state("load")
                assert page.title() == title, (rel, page.title())
                assert page.locator("article h1").first.inner_text().strip().startswith(heading), rel
                # the navigation: the site's sections, each a working link
                nav = page.locator("nav.md-nav--primary a.md-nav__link")
                assert nav.count() >= 20, (rel, nav.count())
                labels = " ".join(page.locator("nav.md-nav--primary").first.text_content().split())
                for section in ("Getting started", "Troubleshooting", "Design notes", "Python API"):
                    assert section in labels, (rel, section)
                shot = tmp_path / (rel.replace("/", "_") + ".png")
                page.screenshot(path=str(shot))
                with Image.open(shot) as im:
                    pixels = np.asarray(im.convert("L"), dtype=np.float32)
                assert pixels.shape == (900, 1280)
                # not blank: text and a coloured header, not one flat colour
                assert pixels.std() > 20 and (pixels < 100).mean() > 0.01, (rel, pixels.std())
            # the API page holds the rendered objects, with their signatures
            page.goto(base + "reference/api.html")
            assert page.locator(".doc-object").count() >= 10
            assert page.locator(".doc-signature").count() >= 10
        finally:
            browser.close()
            server.shutdown()
            server.server_close()
    assert not errors, errors
