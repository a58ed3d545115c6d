"""The import structure: no cycles between modules, no private names imported across modules.

The layers themselves (cli -> store -> engine -> primitives; the library never imports the studies)
are the import-linter contract in ``.importlinter`` (``make layers``); this test adds what that
contract cannot say. Both read the source with grimp, so they need no import of the package."""

import re

import grimp
import pytest

PACKAGE = "seqbayes"


@pytest.fixture(scope="module")
def graph():
    return grimp.build_graph(PACKAGE, include_external_packages=False)


def _cycles(graph):
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index, low, stack, on_stack, found, counter = {}, {}, [], set(), [], [0]
    edges = {m: sorted(graph.find_modules_directly_imported_by(m)) for m in graph.modules}
    # a package's __init__ re-exporting its children is not a cycle of the code
    for m, targets in edges.items():
        edges[m] = [t for t in targets if not t.startswith(m + ".")]
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(edges[root]))]
        index[root] = low[root] = counter[0]; counter[0] += 1
        stack.append(root); on_stack.add(root)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter[0]; counter[0] += 1
                    stack.append(child); on_stack.add(child)
                    work.append((child, iter(edges[child])))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop(); on_stack.discard(member); component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return found


def test_no_import_cycles(graph):
    assert _cycles(graph) == []


_PRIVATE = re.compile(r"\bimport\b(.*)")


def test_no_private_names_imported_across_modules(graph):
    offenders = []
    for importer in sorted(graph.modules):
        for imported in graph.find_modules_directly_imported_by(importer):
            for detail in graph.get_import_details(importer=importer, imported=imported):
                names = _PRIVATE.search(detail["line_contents"])
                if names is None:
                    continue
                private = [n.strip(" ()").split(" as ")[0] for n in names.group(1).split(",")]
                private = [n for n in private if n.startswith("_") and not n.startswith("__")]
                if private:
                    offenders.append(f"{importer}:{detail['line_number']} imports {private} from {imported}")
    assert offenders == []


def test_no_module_over_800_lines():
    from pathlib import Path

    import seqbayes

    root = Path(seqbayes.__file__).parent
    long = {str(p.relative_to(root)): n for p in root.rglob("*.py") if (n := len(p.read_text().splitlines())) > 800}
    assert long == {}


def test_the_public_api_is_what_a_user_types():
    import seqbayes

    assert len(seqbayes.__all__) <= 25
    assert all(hasattr(seqbayes, name) for name in seqbayes.__all__)
