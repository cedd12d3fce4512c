"""The documentation (docs/mkdocs.yml, pages in docs/src/, and the README): the site builds in
strict mode, and every code block in it runs or says why it cannot.

Blocks, as the pages write them (docs/src/design/testing.md says the same to a writer):
- ```python and ```bash blocks run, in order, page by page, in a fresh folder that links
  `scenes/` from the repository: python blocks as scripts (`python3 block.py`, so a snippet
  that needs an `if __name__ == "__main__":` guard fails without one), bash blocks with
  `bash -euo pipefail`;
- a block with `title="FILE"` (rendered as a file name above the block) is written to FILE
  before the blocks after it run, and is not run itself;
- `<!-- no-run: reason -->` on the line right above a python or bash block (blank lines
  between are allowed) leaves it out, and is counted; an empty reason, or a marker on a block
  that would not run anyway, fails;
- any other fence names a data language (toml, yaml, text, ...); an unlabelled fence or an
  unknown language fails, so that no code block escapes by its spelling.
A page's `--8<-- "FILE.md"` (pymdownx.snippets) brings FILE's blocks into the page.
"""

from __future__ import annotations

import os
import re
import shlex
import socket
import subprocess
import sys
import time
import urllib.request
from dataclasses import dataclass

import pytest

from helpers import stop_process

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOCS = os.path.join(ROOT, "docs")
SRC = os.path.join(DOCS, "src")

RUN = {"python", "bash"}
DATA = {"toml", "yaml", "text", "json", "csv", "ini", "html"}
FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})\s*([^\s`{]*)\s*(.*)$")
NO_RUN = re.compile(r"^\s*<!--\s*no-run:\s*(.*?)\s*-->\s*$")
INCLUDE = re.compile(r'^\s*-{1,}8<-{1,}\s+"([^"]+)"\s*$')
TITLE = re.compile(r'title="([^"]+)"')
BLOCK_TIMEOUT = 300  # s: the slowest block (a render) takes about 15 s here


@dataclass
class Block:
    where: str          # file:line of the opening fence
    lang: str
    code: str
    title: str | None   # title="FILE": a file to write
    no_run: str | None  # the marker's reason

    @property
    def kind(self) -> str:
        if self.lang in RUN:
            return "file" if self.title else ("no-run" if self.no_run is not None else "run")
        return "file" if self.title else "data"


def pages() -> list[str]:
    """Every page of the site, and the README (relative to the repository)."""
    found = [os.path.relpath(os.path.join(d, f), ROOT)
             for d, _, files in os.walk(SRC) for f in files if f.endswith(".md")]
    return sorted(found) + ["README.md"]


def blocks_of(page: str, errors: list[str], _seen=()) -> list[Block]:
    """The fenced blocks of `page` in order, with those of the Markdown files it includes;
    what breaks the conventions goes to `errors`."""
    lines = open(os.path.join(ROOT, page), encoding="utf-8").read().split("\n")
    out: list[Block] = []
    marker: tuple[int, str] | None = None  # (line, reason) of a no-run marker awaiting its block
    i = 0
    while i < len(lines):
        line = lines[i]
        inc = INCLUDE.match(line)
        if inc and inc.group(1).endswith(".md"):
            path = inc.group(1)
            if path in _seen:
                errors.append(f"{page}:{i + 1}: {path} includes itself")
            else:
                out += blocks_of(path, errors, _seen + (page,))
            i += 1
            continue
        m = NO_RUN.match(line)
        if m:
            if marker:
                errors.append(f"{page}:{marker[0]}: a no-run marker with no block after it")
            marker = (i + 1, m.group(1))
            if not m.group(1):
                errors.append(f"{page}:{i + 1}: a no-run marker must say why")
            i += 1
            continue
        f = FENCE.match(line)
        if not f:
            if line.strip() and marker:
                errors.append(f"{page}:{marker[0]}: a no-run marker must stand right above its block")
                marker = None
            i += 1
            continue
        indent, fence, lang, info = f.groups()
        j = i + 1
        while j < len(lines) and not (lines[j].strip().startswith(fence[0] * len(fence))
                                      and lines[j].strip().strip(fence[0]) == ""):
            j += 1
        code = "\n".join(x[len(indent):] if x.startswith(indent) else x.lstrip() for x in lines[i + 1:j])
        title = TITLE.search(info)
        block = Block(f"{page}:{i + 1}", lang, code + "\n", title.group(1) if title else None,
                      marker[1] if marker else None)
        if not lang:
            errors.append(f"{block.where}: a fence without a language (use text for output, a "
                          "tree or a layout)")
        elif lang not in RUN | DATA:
            errors.append(f"{block.where}: fence language {lang!r}: code is python or bash, data "
                          f"one of {sorted(DATA)}")
        if marker and block.kind != "no-run":
            errors.append(f"{page}:{marker[0]}: a no-run marker on a block that does not run anyway")
        marker = None
        out.append(block)
        i = j + 1
    if marker:
        errors.append(f"{page}:{marker[0]}: a no-run marker with no block after it")
    return out


def test_every_block_runs_or_says_why():
    """The conventions above hold on every page, and the count of each kind is printed."""
    errors: list[str] = []
    counts = {"run": 0, "no-run": 0, "file": 0, "data": 0}
    reasons = []
    for page in pages():
        for b in blocks_of(page, errors):
            counts[b.kind] += 1
            if b.kind == "no-run":
                reasons.append(f"  {b.where}: {b.no_run}")
    print(f"code blocks: {counts['run']} run, {counts['no-run']} marked no-run, {counts['file']} "
          f"written as files, {counts['data']} data\n" + "\n".join(reasons))
    assert not errors, "\n".join(errors)
    assert counts["run"] >= 15, counts  # the tutorial and the how-to pages run


def _runnable_pages():
    """The pages with a block to run; those that path-trace need Mitsuba."""
    out = []
    for page in pages():
        run = [b for b in blocks_of(page, []) if b.kind == "run"]
        if run:
            mitsuba = any("radiosity reference" in b.code or "--reference auto" in b.code for b in run)
            out.append(pytest.param(page, marks=[pytest.mark.needs("mitsuba")] if mitsuba else []))
    return out


@pytest.mark.cluster
@pytest.mark.parametrize("page", _runnable_pages())
def test_page_blocks_run(page, tmp_path):
    """Every runnable block of `page`, in order, in a fresh folder: as a reader who copies them
    one after the other would."""
    errors: list[str] = []
    blocks = blocks_of(page, errors)
    os.symlink(os.path.join(ROOT, "scenes"), tmp_path / "scenes")
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONUNBUFFERED="1",
               PATH=os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", ""))
    for k, b in enumerate(blocks):
        if b.kind == "file":
            path = tmp_path / b.title
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(b.code)
        elif b.kind == "run":
            script = tmp_path / f"_block{k}.{'py' if b.lang == 'python' else 'sh'}"
            script.write_text(b.code)
            cmd = [sys.executable, script.name] if b.lang == "python" else \
                ["bash", "-euo", "pipefail", script.name]
            try:
                r = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True,
                                   timeout=BLOCK_TIMEOUT)
            except subprocess.TimeoutExpired as e:
                pytest.fail(f"{b.where}: still running after {BLOCK_TIMEOUT} s:\n{b.code}\n"
                            f"{(e.stdout or '')[-3000:]}", pytrace=False)
            if r.returncode != 0:
                pytest.fail(f"{b.where}: exit status {r.returncode}:\n{b.code}\n--- output:\n"
                            f"{(r.stdout + r.stderr)[-4000:]}", pytrace=False)


def readme_docs_commands() -> list[str]:
    """The commands of the README's "Building the docs" block, comments dropped."""
    readme = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    part = readme[readme.index("## Building the docs"):]
    part = part[:part.index("\n## ", 5)]
    (block,) = re.findall(r"```bash\n(.*?)\n```", part, re.S)
    return [line.split("#")[0].strip() for line in block.split("\n") if line.split("#")[0].strip()]


def clean_env() -> dict:
    """The environment of a reader's shell after `pip install -e .`: the interpreter's scripts
    first on PATH and no PYTHONPATH (with one, griffe finds `radiosity` through it, and a
    console script that cannot find the package would pass)."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", "")
    return env


def test_the_readme_docs_commands_are_the_ones_tested():
    """The build and serve lines that the tests below run are the README's, word for word."""
    assert readme_docs_commands() == ["python3 -m pip install -e '.[test]'",
                                      "mkdocs serve -f docs/mkdocs.yml",
                                      "mkdocs build --strict -f docs/mkdocs.yml"]


def test_the_site_builds_strictly(tmp_path):
    """The README's `mkdocs build --strict -f docs/mkdocs.yml` (the console script, from the
    repository, in a clean environment; into a temporary folder, not docs/build/): a broken
    link or anchor, a missing include, a bad API or CLI reference fails the build; and the
    generated references hold every command and the API."""
    site = tmp_path / "site"
    command = shlex.split(readme_docs_commands()[2]) + ["-d", str(site)]
    env = clean_env()
    r = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stdout + r.stderr
    # the commands of the package that mkdocs-click documented (the one installed)
    commands = subprocess.run([sys.executable, "-c", "from radiosity.cli.commands import main; "
                               "print(*main.commands)"], cwd=ROOT, env=env, capture_output=True,
                              text=True, timeout=120, check=True).stdout.split()

    cli = (site / "reference" / "cli" / "index.html").read_text()
    missing = [name for name in commands if f'id="radiosity-{name}"' not in cli]
    assert commands and not missing, f"the CLI reference lacks {missing}"
    assert "exact|seed|none" in cli  # what `radiosity preprocess --help` offers
    api = (site / "reference" / "python" / "index.html").read_text()
    for name in ("radiosity.pipeline.render", "radiosity.viewfactors.api.viewfactors",
                 "radiosity.settings.Settings", "radiosity.errors.RadiosityError"):
        assert f'id="{name}"' in api, name
    assert (site / "tutorial" / "index.html").exists()


@pytest.mark.cluster  # a server subprocess that builds the whole site first
def test_the_readme_serve_command_serves_the_site(tmp_path):
    """The README's `mkdocs serve -f docs/mkdocs.yml`, as written but on a free loopback port
    (`-a`: 8000 may be taken, by another run of this test too): the site answers, the API
    reference with it."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    command = shlex.split(readme_docs_commands()[1]) + ["-a", f"127.0.0.1:{port}", "--no-livereload"]
    log = open(tmp_path / "serve.log", "w+")
    proc = subprocess.Popen(command, cwd=ROOT, env=clean_env(), stdout=log, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 240
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/reference/python/",
                                            timeout=10) as page:
                    api = page.read().decode()
                break
            except OSError:
                log.seek(0)
                assert proc.poll() is None, f"mkdocs serve exited {proc.returncode}:\n{log.read()}"
                assert time.monotonic() < deadline, f"no answer on port {port}:\n{log.read()}"
                time.sleep(1)
    finally:
        stop_process(proc, 20)
        log.close()
    assert 'id="radiosity.pipeline.render"' in api


def test_ci_runs_the_readme_test_command():
    """.ci/run's last line is the README's second Quick start command, as written there."""
    readme = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    quick = readme[readme.index("## Quick start"):]
    quick = quick[:quick.index("\n## ", 5)]
    commands = re.findall(r"```bash\n(.*?)\n```", quick, re.S)
    assert len(commands) == 2, commands
    ci = [x for x in open(os.path.join(ROOT, ".ci", "run")).read().split("\n") if x.strip()]
    assert ci[-1] == commands[1] == "python3 -m pip install -e '.[test]' && python3 -m pytest"
