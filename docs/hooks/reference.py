"""Reference pages generated at build time from the code: the settings and the command line.

A page asks for a generated section with a marker line of its own:

* ``<!-- teamslam:settings MODULE:CLASS -->`` — every field of a settings dataclass: name,
  type, default and the description from the class docstring's numpy-style ``Attributes``
  section. A field whose type is itself a dataclass is a group: its fields are listed as
  ``group.name`` with the descriptions of the nested class's docstring, to any depth.
* ``<!-- teamslam:cli -->`` — every ``teamslam`` command and subcommand with its usage and
  options, as argparse prints them (``teamslam.cli.build_parser``).

Used by mkdocs as a hook (``hooks:`` in ``mkdocs.yml``); :class:`RolesAsCode` is a griffe
extension (``extensions:`` of mkdocstrings) that shows the Sphinx roles of the docstrings
(``:func:`~teamslam.api.run```) as inline code, so the API pages read like the source.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import math
import os
import re
import typing

import griffe

MARKER = re.compile(r"^<!-- teamslam:(settings|cli)(?: +([\w.]+):(\w+))? -->$", re.M)
ROLE = re.compile(r":(?:py:)?[a-z]+:`~?([^`<]*?)(?: *<([^>]+)>)?`")
LITERAL_MARKER = re.compile(r"(?<=\S)::$", re.M)  # reST "text::" before an indented block


def roles_as_code(text: str) -> str:
    """Sphinx roles as inline code: ``:role:`~a.b.c``` → ```c```, ``:role:`a.b.c``` →
    ```a.b.c```, ``:role:`text <a.b>``` → ```text```."""

    def code(match: re.Match) -> str:
        target = match.group(1).strip()
        short = match.group(0).split("`")[1].startswith("~")
        return f"`{target.rsplit('.', 1)[-1] if short else target}`"

    return ROLE.sub(code, text)


class RolesAsCode(griffe.Extension):
    """Rewrite Sphinx roles in every docstring as inline code before it is rendered, and a
    reST literal-block marker ``text::`` as ``text:`` (the indented block after it is code in
    Markdown as it is)."""

    def on_object(self, *, obj: griffe.Object, **kwargs: typing.Any) -> None:
        if obj.docstring is not None:
            text = roles_as_code(obj.docstring.value)
            obj.docstring.value = LITERAL_MARKER.sub(":", text)


# --------------------------------------------------------------------------------------------
# settings


@dataclasses.dataclass
class Setting:
    """One documented field: its dotted name, type, default and description (Markdown)."""

    name: str
    type: str
    default: str
    description: str
    group: bool = False


def _attribute_docs(cls: type) -> dict[str, str]:
    """Field name → description, from the ``Attributes`` section of ``cls``'s docstring."""
    docs: dict[str, str] = {}
    docstring = griffe.Docstring(cls.__doc__ or "", parser="numpy")
    for section in docstring.parse(warnings=False):
        if section.kind is griffe.DocstringSectionKind.attributes:
            for item in section.value:
                for name in item.name.split(","):
                    docs[name.strip()] = item.description.strip()  # Markdown as written
    return docs


def _type_name(field: dataclasses.Field, hint: typing.Any) -> str:
    if isinstance(field.type, str):
        return field.type
    return getattr(hint, "__name__", str(hint))


def _default(field: dataclasses.Field) -> str:
    if field.default is not dataclasses.MISSING:
        value = field.default
    elif field.default_factory is not dataclasses.MISSING:
        value = field.default_factory()
    else:
        return "required"
    if isinstance(value, float) and math.isinf(value):
        return "inf" if value > 0 else "-inf"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return value
    return repr(value)


def settings_of(cls: type, prefix: str = "") -> list[Setting]:
    """Every field of the dataclass ``cls``, nested dataclasses as groups ``group.name``."""
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    docs = _attribute_docs(cls)
    hints = typing.get_type_hints(cls, vars(importlib.import_module(cls.__module__)))
    out: list[Setting] = []
    for field in dataclasses.fields(cls):
        if not field.init or field.name.startswith("_"):
            continue
        name = prefix + field.name
        hint = hints.get(field.name)
        description = roles_as_code(docs.get(field.name, ""))
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            out.append(Setting(name, hint.__name__, "", description, group=True))
            out.extend(settings_of(hint, prefix=name + "."))
        else:
            out.append(Setting(name, _type_name(field, hint), _default(field), description))
    return out


def settings_markdown(cls: type, heading: str = "###") -> str:
    """The settings of ``cls`` as Markdown: a heading (and anchor) per setting."""
    lines = []
    for setting in settings_of(cls):
        depth = heading + "#" * setting.name.count(".")
        lines.append(f"{depth} `{setting.name}`")
        lines.append("")
        if setting.group:
            lines.append(f"Group of settings (`{setting.type}`).")
        else:
            lines.append(f"Type `{setting.type}`, default `{setting.default}`.")
        lines.append("")
        if setting.description:
            lines.append(setting.description)
            lines.append("")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# command line


def _subcommands(parser: argparse.ArgumentParser) -> list[tuple[str, str, argparse.ArgumentParser]]:
    """``(name, one-line help, parser)`` of the subcommands of ``parser``, in their order."""
    out = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            seen = set()
            for name, sub in action.choices.items():
                if id(sub) in seen:  # an alias
                    continue
                seen.add(id(sub))
                out.append((name, helps.get(name, ""), sub))
    return out


def _walk(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    for name, summary, sub in _subcommands(parser):
        yield (*path, name), summary, sub
        yield from _walk(sub, (*path, name))


def cli_markdown(parser: argparse.ArgumentParser | None = None) -> str:
    """Every command of ``teamslam``: a summary table, then each command's ``--help``."""
    if parser is None:
        from teamslam.cli import build_parser

        parser = build_parser()
    commands = list(_walk(parser))
    lines = ["| command | what it does |", "| --- | --- |"]
    for path, summary, _ in commands:
        anchor = "teamslam-" + "-".join(path)
        text = " ".join(summary.split()).replace("|", "\\|")
        lines.append(f"| [`teamslam {' '.join(path)}`](#{anchor}) | {text} |")
    lines.append("")
    for path, _, sub in [((), "", parser), *commands]:
        title = " ".join(("teamslam", *path))
        anchor = "-".join(("teamslam", *path))
        lines.append(f"{'#' * min(2 + len(path), 6)} `{title}` {{#{anchor}}}")
        lines.append("")
        lines.append("```text")
        lines.append(sub.format_help().rstrip())
        lines.append("```")
        lines.append("")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# the mkdocs hook


def expand(markdown: str) -> str:
    """``markdown`` with every marker replaced by what it asks for."""

    def replace(match: re.Match) -> str:
        if match.group(1) == "cli":
            return cli_markdown()
        cls = getattr(importlib.import_module(match.group(2)), match.group(3))
        return settings_markdown(cls)

    previous = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "88"  # argparse wraps help to the terminal; the page has a width
    try:
        return MARKER.sub(replace, markdown)
    finally:
        if previous is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = previous


def on_page_markdown(markdown: str, **kwargs: typing.Any) -> str:
    """mkdocs hook: expand the generated sections of a page."""
    return expand(markdown)
