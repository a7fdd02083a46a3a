#!/usr/bin/env python3
"""The layering that docs/ARCHITECTURE.md states, checked: no module cycles inside a crate,
and each crate imports only the crates its row allows (normal dependencies; dev-dependencies
are free). Exits 1 with the offending cycle or import. Run by .ci/run.

A module depends on another when its code (not its comments) names `crate::other` or
`super::other` (other than its own tests). Doc links do not count: they make no build
dependency."""
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parents[2]

# What each crate may import (sylva crates only), as docs/ARCHITECTURE.md's table says.
ALLOWED = {
    "sylva-core": set(),
    "sylva-geom": {"sylva-core"},
    "sylva-grid": {"sylva-core"},
    "sylva-grow": {"sylva-core", "sylva-geom"},
    "sylva-io": {"sylva-core", "sylva-geom"},
    "sylva-scene": {"sylva-core", "sylva-geom", "sylva-grow", "sylva-io"},
    "sylva-lb": {"sylva-core", "sylva-geom", "sylva-grid"},
    "sylva-voxel": {"sylva-core", "sylva-geom", "sylva-grid"},
    "sylva-wgpu": {"sylva-core"},
    "sylva-lb-gpu": {"sylva-core", "sylva-grid", "sylva-lb", "sylva-wgpu"},
    "sylva-trace": {"sylva-core", "sylva-geom"},
    "sylva-trace-gpu": {"sylva-core", "sylva-geom", "sylva-trace", "sylva-wgpu"},
    "sylva-light": {"sylva-core", "sylva-geom", "sylva-grid", "sylva-lb", "sylva-voxel", "sylva-trace"},
    "sylva-render": {"sylva-core", "sylva-geom", "sylva-grid", "sylva-lb", "sylva-light",
                     "sylva-trace", "sylva-trace-gpu", "sylva-wgpu"},
    "sylva-spp": {"sylva-core", "sylva-geom", "sylva-grid", "sylva-lb", "sylva-voxel",
                  "sylva-trace", "sylva-light"},
    # The canopy radiation budget: abstract stands, bands, the Monte Carlo budget and the
    # lattice budget held to it.
    "sylva-budget": {"sylva-core", "sylva-geom", "sylva-grid", "sylva-grow", "sylva-lb", "sylva-trace"},
    # Transport and queue only: what runs on the ranks is the pipeline's (jobs of a Runner).
    "sylva-mpi": {"sylva-core"},
    "sylva-pipeline": {"sylva-core", "sylva-geom", "sylva-grid", "sylva-lb", "sylva-voxel",
                       "sylva-scene", "sylva-trace", "sylva-trace-gpu", "sylva-wgpu",
                       "sylva-light", "sylva-render", "sylva-spp", "sylva-budget"},
    # The viewer serves frames of a prepared scene: the pipeline's, nothing the pipeline hides.
    "sylva-view": {"sylva-core", "sylva-geom", "sylva-lb", "sylva-light", "sylva-render",
                   "sylva-pipeline"},
    "sylva-fuzz": {"sylva-core", "sylva-geom", "sylva-grid", "sylva-grow", "sylva-io",
                   "sylva-lb", "sylva-scene"},
    "sylva-testkit": None,  # dev-only: anything
    "sylva-cli": None,  # the front end: anything
}


def dependencies(manifest: pathlib.Path) -> set:
    deps, section = set(), None
    for line in manifest.read_text().splitlines():
        s = line.strip()
        if s.startswith("["):
            section = s
            continue
        m = re.match(r"(sylva-[a-z-]+)\s*(\.workspace|=)", s)
        if m and section is not None and section.endswith("dependencies]") and "dev-" not in section:
            deps.add(m.group(1))
    return deps


def strip_comments(text: str) -> str:
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    return "\n".join(line.split("//", 1)[0] for line in text.splitlines())


def without_tests(text: str) -> str:
    i = text.find("#[cfg(test)]")
    return text if i < 0 else text[:i]


def module_name(src: pathlib.Path, f: pathlib.Path) -> str:
    rel = f.relative_to(src).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] in ("lib", "main", "mod"):
        parts = parts[:-1]
    return "::".join(parts) or "crate"


def module_graph(src: pathlib.Path) -> dict:
    files = [f for f in src.rglob("*.rs") if "bin" not in f.relative_to(src).parts[:1]]
    mods = {module_name(src, f): f for f in files}
    graph = {m: set() for m in mods}
    for m, f in mods.items():
        code = strip_comments(without_tests(f.read_text()))
        parent = m.rsplit("::", 1)[0] if "::" in m else "crate"
        for path in re.findall(r"\bcrate::([a-z_][a-z0-9_]*(?:::[a-z_][a-z0-9_]*)*)", code):
            target = resolve(path.split("::"), mods)
            if target and target != m and not m.startswith(target + "::"):
                graph[m].add(target)
        for path in re.findall(r"\bsuper::([a-z_][a-z0-9_]*)", code):
            base = "" if parent == "crate" else parent + "::"
            target = resolve((base + path).split("::"), mods)
            if target and target != m and not m.startswith(target + "::"):
                graph[m].add(target)
    return graph


def resolve(parts, mods):
    # The longest prefix that is a module.
    for n in range(len(parts), 0, -1):
        name = "::".join(parts[:n])
        if name in mods:
            return name
    return None


def find_cycle(graph: dict):
    state, stack = {}, []

    def visit(n):
        state[n] = 1
        stack.append(n)
        for d in sorted(graph.get(n, ())):
            if state.get(d) == 1:
                return stack[stack.index(d):] + [d]
            if d not in state:
                c = visit(d)
                if c:
                    return c
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state:
            c = visit(n)
            if c:
                return c
    return None


def main() -> int:
    failures = []
    crates = sorted(p for p in (ROOT / "crates").iterdir() if (p / "Cargo.toml").exists())
    for crate in crates:
        name = crate.name
        if name not in ALLOWED:
            failures.append(f"{name}: not in tools/arch/check.py's table (add its row there and in docs/ARCHITECTURE.md)")
            continue
        allowed = ALLOWED[name]
        if allowed is not None:
            extra = dependencies(crate / "Cargo.toml") - allowed
            if extra:
                failures.append(f"{name} imports {', '.join(sorted(extra))}, which its row does not allow")
        cycle = find_cycle(module_graph(crate / "src"))
        if cycle:
            failures.append(f"{name}: module cycle {' -> '.join(cycle)}")
    for f in failures:
        print("architecture:", f)
    if not failures:
        print(f"architecture: {len(crates)} crates, their imports as docs/ARCHITECTURE.md allows, no module cycles")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
