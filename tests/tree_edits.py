"""Walking and mutating nested JSON-like data (dicts and lists), for the property tests of the parsers."""

import copy


def nodes(tree, prefix=()):
    """(path, value) of every node below the root; a path is the tuple of keys and list indices leading to it."""
    items = tree.items() if isinstance(tree, dict) else enumerate(tree) if isinstance(tree, list) else ()
    for key, value in items:
        yield prefix + (key,), value
        yield from nodes(value, prefix + (key,))


def replaced(tree, path, value, delete=False):
    """A deep copy of ``tree`` with the node at ``path`` set to ``value`` (or deleted)."""
    out = copy.deepcopy(tree)
    node = out
    for key in path[:-1]:
        node = node[key]
    if delete:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return out
