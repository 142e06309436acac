"""Reading URDF text into an XML tree: size caps, hardened parsing (defusedxml: no DTD,
no entities, no external references), the junk exporters leave around the document,
and files that are still xacro. ``urdf.py`` reads the kinematics from the tree."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET

import defusedxml
import defusedxml.ElementTree as DET

from ..errors import InvalidModel

# Dropped around the document: a byte-order mark or blank lines before <?xml (which
# must be the first characters), NULs after the root (a C string written whole).
_LEADING_JUNK = "\ufeff \t\r\n"
_TRAILING_JUNK = "\x00 \t\r\n"


def parse_urdf_xml(text: str, max_bytes: int) -> ET.Element:
    """The document's <robot> element, or ``InvalidModel`` (field ``urdf``) for text that
    is too large, not XML, hostile (a DTD, entities, external references) or xacro."""
    if not isinstance(text, str):
        raise InvalidModel(f"URDF must be text (str), got {type(text).__name__}", field="urdf")
    # len(text) <= UTF-8 size, so the cheap test first spares encoding a huge string.
    if len(text) > max_bytes:
        raise InvalidModel(f"URDF is larger than {max_bytes} bytes", field="urdf")
    try:
        size = len(text.encode("utf-8"))
    except UnicodeEncodeError:
        raise InvalidModel("URDF is not valid Unicode (lone surrogate)", field="urdf") from None
    if size > max_bytes:
        raise InvalidModel(f"URDF is larger than {max_bytes} bytes ({size})", field="urdf")
    text = text.lstrip(_LEADING_JUNK).rstrip(_TRAILING_JUNK)
    try:
        root: ET.Element = DET.fromstring(text, forbid_dtd=True)
    except defusedxml.DTDForbidden:
        raise InvalidModel("URDF must not contain a DTD (<!DOCTYPE ...>)", field="urdf") from None
    except defusedxml.EntitiesForbidden:
        raise InvalidModel("URDF must not declare entities", field="urdf") from None
    except defusedxml.ExternalReferenceForbidden:
        raise InvalidModel("URDF must not reference external resources", field="urdf") from None
    except (defusedxml.DefusedXmlException, ET.ParseError) as e:
        raise InvalidModel(f"URDF is not well-formed XML: {e}", field="urdf") from None
    if local_name(root) != "robot":
        raise InvalidModel(f"root element must be <robot>, got <{local_name(root)}>", field="urdf")
    _refuse_xacro(root)
    return root


# xacro's namespace under any URI naming it (files declare http://www.ros.org/wiki/xacro,
# http://ros.org/wiki/xacro, ...; xacro reads the prefix), and ${...} / $(...) in a value.
_XACRO_TAG = re.compile(r"\{[^}]*xacro[^}]*\}(.+)", re.IGNORECASE)
_XACRO_VALUE = re.compile(r"\$[{(]")


def _refuse_xacro(root: ET.Element) -> None:
    """Refuse a file that is still xacro: an element of xacro's namespace (read as URDF,
    an ``<xacro:if>`` block's joints were silently left out), or ``${...}`` / ``$(...)``
    in a link or joint (a leftover in a mesh path, not read here, is let through)."""
    tags = (_XACRO_TAG.fullmatch(e.tag) for e in root.iter() if isinstance(e.tag, str))
    found = next((f"<xacro:{t.group(1)}>" for t in tags if t is not None), None)
    for element in (e for e in root if local_name(e) in ("link", "joint")):
        parts = [element] if local_name(element) == "link" else [element, *element]
        values = ((k, v, p) for p in parts for k, v in p.attrib.items())
        bad = (f"{k}={v!r} in <{local_name(p)}>" for k, v, p in values if _XACRO_VALUE.search(v))
        found = found or next(bad, None)
    if found is not None:
        raise InvalidModel(
            f"the file is xacro, not URDF ({found}): expand it first, e.g. "
            "`xacro robot.urdf.xacro > robot.urdf`",
            field="urdf",
        )


def local_name(element: ET.Element) -> str:
    """Tag without a namespace: some exporters put URDF in a default xmlns."""
    tag = element.tag
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def first_child(element: ET.Element, name: str) -> ET.Element | None:
    """The first child element whose tag (without a namespace) is ``name``."""
    return next((c for c in element if local_name(c) == name), None)
