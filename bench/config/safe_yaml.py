"""YAML for files people edit and attackers may hand us: a mapping or one clear line why not.

Built on PyYAML's SafeLoader with the limits a config needs and nothing more:
a size cap, strict UTF-8 without control characters, no anchors or aliases
(the "billion laughs" expansion, and a config has no use for them), a nesting
limit, duplicate keys refused (with both lines), and integers of sane length.
Every message quotes the input at most :data:`QUOTE` characters long.
"""

from __future__ import annotations

from pathlib import Path

import yaml
from yaml.composer import Composer
from yaml.constructor import ConstructorError, SafeConstructor
from yaml.events import AliasEvent
from yaml.nodes import MappingNode

from drivers.errors import YamlRefused

MAX_BYTES = 1 << 20
MAX_DEPTH = 32
MAX_INT_DIGITS = 30
QUOTE = 60


def quote(text: object) -> str:
    s = str(text)
    return repr(s if len(s) <= QUOTE else s[:QUOTE] + "…")


class _Loader(yaml.SafeLoader):
    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):  # noqa: ANN001 - PyYAML's signature
        if self.check_event(AliasEvent):
            mark = self.peek_event().start_mark
            raise YamlRefused(f"line {mark.line + 1}: aliases (*name) are not allowed in a config; "
                              f"write the value out")
        event = self.peek_event()
        if getattr(event, "anchor", None):
            raise YamlRefused(f"line {event.start_mark.line + 1}: anchors (&name) are not allowed "
                              f"in a config")
        self._depth += 1
        if self._depth > MAX_DEPTH:
            raise YamlRefused(f"line {event.start_mark.line + 1}: nested deeper than {MAX_DEPTH} "
                              f"levels")
        try:
            return Composer.compose_node(self, parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node: MappingNode, deep: bool = False):  # noqa: ANN201
        seen: dict[object, int] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                hash(key)
            except TypeError:
                raise YamlRefused(f"line {key_node.start_mark.line + 1}: a key must be a plain "
                                  f"value") from None
            line = key_node.start_mark.line + 1
            if key in seen:
                raise YamlRefused(f"line {line}: duplicate key {quote(key)} (first on line "
                                  f"{seen[key]}); keep one")
            seen[key] = line
        return SafeConstructor.construct_mapping(self, node, deep=deep)

    def construct_yaml_int(self, node):  # noqa: ANN001, ANN201
        digits = sum(ch.isdigit() for ch in str(node.value))
        if digits > MAX_INT_DIGITS:
            raise YamlRefused(f"line {node.start_mark.line + 1}: an integer of {digits} digits is "
                              f"not a plausible value")
        return SafeConstructor.construct_yaml_int(self, node)


_Loader.add_constructor("tag:yaml.org,2002:int", _Loader.construct_yaml_int)


def parse(raw: bytes, name: str = "<config>") -> object:
    """The document in ``raw``, or :class:`YamlRefused` naming what is wrong."""
    if len(raw) > MAX_BYTES:
        raise YamlRefused(f"{len(raw)} bytes, more than the {MAX_BYTES} a config may have")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise YamlRefused(f"not UTF-8 text (byte {e.start}: 0x{raw[e.start]:02x})") from None
    for i, ch in enumerate(text):
        if (ch < " " and ch not in "\t\n\r") or ch in "\x7f\ufffe\uffff":
            line = text.count("\n", 0, i) + 1
            raise YamlRefused(f"line {line}: control character U+{ord(ch):04X} in the file")
    loader = _Loader(text)
    try:
        return loader.get_single_data()
    except YamlRefused:
        raise
    except (yaml.YAMLError, ConstructorError) as e:
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        problem = getattr(e, "problem", None) or str(e)
        raise YamlRefused(f"not valid YAML: {where}{problem}".replace("\n", " ")) from None
    except RecursionError:
        raise YamlRefused(f"nested deeper than {MAX_DEPTH} levels") from None
    finally:
        loader.dispose()


def read_mapping(path: Path) -> dict:
    """A YAML file whose top level is a mapping; :class:`YamlRefused` otherwise."""
    path = Path(path)
    with open(path, "rb") as f:
        raw = f.read(MAX_BYTES + 1)
    data = parse(raw, str(path))
    if not isinstance(data, dict):
        raise YamlRefused("expected a mapping of fields at the top level")
    return data
