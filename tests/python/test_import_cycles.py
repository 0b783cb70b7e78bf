"""No import cycle between any two Python files of `worldsplat` / `worldsplat_models`.

import-linter's `acyclic_siblings` contract (pyproject.toml) checks siblings at every depth; a package and one of
its own modules importing each other (`pkg/__init__.py` <-> `pkg/reader.py`, even through a function-level import)
is not a pair of siblings, so this reads the same graph with grimp (import-linter's own reader, function-level
imports included) and asks for any strongly connected group of modules.
"""

import grimp


def _cycles(graph) -> list[list[str]]:
    """Tarjan's strongly connected components of more than one module (or a module importing itself)."""
    adj = {m: sorted(graph.find_modules_directly_imported_by(m)) for m in sorted(graph.modules)}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []
    counter = 0
    for root in adj:
        if root in index:
            continue
        work = [(root, iter(adj[root]))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(adj[w])))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    group = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        group.append(w)
                        if w == v:
                            break
                    if len(group) > 1 or v in adj[v]:
                        groups.append(sorted(group))
    return groups


def _describe(graph, group: list[str]) -> str:
    lines = []
    for a in group:
        for b in sorted(graph.find_modules_directly_imported_by(a)):
            if b in group:
                for d in graph.get_import_details(importer=a, imported=b):
                    lines.append(f"  {a}:{d['line_number']} {d['line_contents']}")
    return "\n".join(lines)


def test_the_cycle_finder_sees_a_package_and_its_module():
    g = grimp.ImportGraph()
    for m in ("pkg", "pkg.reader", "pkg.other"):
        g.add_module(m)
    g.add_import(importer="pkg", imported="pkg.reader", line_number=1, line_contents="x")
    g.add_import(importer="pkg.reader", imported="pkg", line_number=2, line_contents="y")
    g.add_import(importer="pkg", imported="pkg.other", line_number=3, line_contents="z")
    assert _cycles(g) == [["pkg", "pkg.reader"]]


def test_no_import_cycle_between_any_two_files():
    graph = grimp.build_graph(
        "worldsplat", "worldsplat_models", include_external_packages=False, exclude_type_checking_imports=True
    )
    assert len(graph.modules) > 100  # the whole tree was read
    cycles = _cycles(graph)
    assert not cycles, "import cycles:\n" + "\n".join(_describe(graph, c) for c in cycles)
