"""GLSL source loading: files under the top-level `shaders/` (installed as `renderer/shaders`),
composed by `#include` and `#define`, with the names of the Python/GLSL contract (contract.py) defined
in every program.

Every included file is given its own GLSL source-string number through `#line <line> <file-id>`
so that a compile error can be mapped back to a file and line; `ShaderError` carries that mapping.
Sources are read once and cached (they do not change while a process runs).
"""

from __future__ import annotations

import functools
import re
from pathlib import Path

import moderngl

from ..errors import ShaderError
from .contract import glsl_defines

# An installed package carries them as renderer/shaders (pyproject.toml); a checkout has them beside it.
_PACKAGED = Path(__file__).resolve().parents[1] / "shaders"
SHADER_DIR = _PACKAGED if _PACKAGED.is_dir() else Path(__file__).resolve().parents[2] / "shaders"
_INCLUDE = re.compile(r'^\s*#include\s+"([^"]+)"\s*$')
# Each file's lines are numbered from a base of its own (file id x LINE_BASE): compile logs name the
# file and line even where the driver ignores #line's source-string number.
LINE_BASE = 100000


@functools.cache
def _read(name: str) -> str:
    path = SHADER_DIR / name
    if not path.is_file():
        raise ShaderError(f"shader file {name!r} not found under {SHADER_DIR}")
    return path.read_text()


def compose(name: str, defines: dict[str, object] | None = None, first_id: int = 0) -> tuple[str, list[str]]:
    """Return (source, files): the composed source and the file name of each source-string number
    (numbers start at `first_id`: a program's fragment stage continues after its vertex stage's)."""
    files: list[str] = []
    lines_out: list[str] = []

    def emit(fname: str, stack: tuple[str, ...]) -> None:
        if fname in stack:
            raise ShaderError(f"circular #include of {fname!r} via {' -> '.join(stack)}")
        fid = first_id + len(files)
        files.append(fname)
        base = fid * LINE_BASE
        lines_out.append(f"#line {base + 1} {fid}")
        for lineno, line in enumerate(_read(fname).splitlines(), start=1):
            m = _INCLUDE.match(line)
            if m:
                emit(m.group(1), stack + (fname,))
                lines_out.append(f"#line {base + lineno + 1} {fid}")
            else:
                lines_out.append(line)

    emit(name, ())
    body = "\n".join(lines_out)
    head = ["#version 450 core"]
    for key, value in {**glsl_defines(), **(defines or {})}.items():
        head.append(f"#define {key} {value}")
    if not body.lstrip().startswith("#line"):
        raise ShaderError("internal: composed shader does not start with #line")
    if "#version" in body:
        raise ShaderError(f"{name}: remove '#version' from shader files; the loader adds it")
    return "\n".join(head) + "\n" + body + "\n", files


def _rewrite_log(log: str, files: list[str]) -> str:
    # Mesa: "0:12(3): error: ..."; NVIDIA: "0(12) : error ..." -- the first number is the source-string
    # number, which Mesa leaves at 0 whatever #line says, so the file is also in the line number.
    def sub(m: re.Match) -> str:
        fid, line = int(m.group(1)), int(m.group(2))
        if line > LINE_BASE:
            fid, line = divmod(line, LINE_BASE)
        fname = files[fid] if fid < len(files) else f"<string {fid}>"
        return f"{fname}:{line}"

    log = re.sub(r"\b(\d+):(\d+)\(\d+\)", sub, log)
    return re.sub(r"\b(\d+)\((\d+)\)", sub, log)


_UNIFORM = re.compile(r"^\s*(?:layout\s*\([^)]*\)\s*)?uniform\s+\w+\s+(\w+)", re.M)


def declared_uniforms(*sources: str) -> frozenset[str]:
    """The names the sources declare as uniforms (whether or not a variant's compiler keeps them)."""
    return frozenset(m.group(1) for src in sources for m in _UNIFORM.finditer(src))


def _build(factory, files: list[str], what: str, *sources: str):
    try:
        prog = factory()
    except moderngl.Error as exc:
        raise ShaderError(f"{what} failed to compile or link:\n{_rewrite_log(str(exc), files)}") from exc
    # What set_uniform checks a name against: the compiler drops the uniforms a variant does not use,
    # a name the sources never declare is a mistake.
    prog.extra = {"declared": declared_uniforms(*sources), "what": what}
    return prog


def set_uniform(prog, name: str, value) -> None:
    """Set a uniform if this program variant uses it (the compiler drops unused ones); a name the
    program's sources do not declare at all is an error, not a silent no-op."""
    if name in prog:
        if isinstance(value, bytes):
            prog[name].write(value)
        else:
            prog[name].value = value
    elif name not in (prog.extra or {}).get("declared", ()):
        raise ShaderError(f"{(prog.extra or {}).get('what', 'the program')} declares no uniform {name!r}")


def compute_shader(ctx: moderngl.Context, name: str, defines: dict | None = None) -> moderngl.ComputeShader:
    src, files = compose(name, defines)
    return _build(lambda: ctx.compute_shader(src), files, name, src)


def program(ctx: moderngl.Context, vertex: str, fragment: str, defines: dict | None = None) -> moderngl.Program:
    vs, vfiles = compose(vertex, defines)
    fs, ffiles = compose(fragment, defines, first_id=len(vfiles))
    return _build(lambda: ctx.program(vertex_shader=vs, fragment_shader=fs), vfiles + ffiles,
                  f"{vertex} + {fragment}", vs, fs)
