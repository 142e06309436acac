"""The glTF 2.0 container: a ``.glb``'s header and chunks (spec section 4.4) or a
``.gltf``'s JSON, the JSON document and its checks before ``gltf`` reads the node graph.

  - GLB: 12-byte header (magic "glTF", version 2, total length equal to the input's
    length), a JSON chunk first, an optional BIN chunk second; unknown chunk types are
    skipped (spec 4.4.3.1). ``.gltf``: the JSON document itself (bytes or str).
  - JSON: UTF-8 (a BOM is allowed), an object; NaN, Infinity and over-deep nesting are
    refused. ``asset.version`` must be 2.x.
  - ``extensionsRequired``: an extension a loader must know to read the file correctly
    (spec 3.12). Those that change only data this reader never reads (meshes,
    accessors, materials, textures, lights, animations: ``REQUIRED_BUT_UNREAD``, and
    any ``<VENDOR>_materials_*`` or ``<VENDOR>_texture_*``) are accepted; any other is
    refused, naming it: it could change the nodes or skins.
  - buffers: only checked, never used. A GLB buffer without ``uri`` must fit the BIN
    chunk; a ``data:`` URI must decode (base64) to at least ``byteLength`` bytes; other
    URIs (external files) are not fetched, which is fine: no buffer data is needed.
    Another buffer without ``uri`` is a meshopt placeholder (gltfpack's output), allowed
    when ``EXT_meshopt_compression`` or ``KHR_meshopt_compression`` is required.

Errors are ``InvalidModel`` with ``joint`` ``glb``, ``json``, ``asset`` or
``buffers[i]`` and ``field`` the member at fault (``extensionsRequired`` with ``json``).
"""

from __future__ import annotations

import base64
import binascii
import json
import re
import struct
from dataclasses import dataclass
from typing import Any

from solver.errors import InvalidModel

MAX_BYTES = 32_000_000  # a whole .glb or .gltf
MAX_JSON_BYTES = 8_000_000  # a GLB's JSON chunk (a .gltf is all JSON: MAX_BYTES)
MAX_BUFFERS = 1024

# Required extensions that change nothing this reader reads (nodes, skins): mesh and
# buffer-view compression, quantized accessors, instancing of meshes, lights, LODs of
# meshes, metadata, animation targets. Materials and textures: _UNREAD_FAMILY.
REQUIRED_BUT_UNREAD = frozenset(
    {
        "KHR_draco_mesh_compression",
        "KHR_mesh_quantization",
        "EXT_meshopt_compression",
        "KHR_meshopt_compression",
        "EXT_mesh_gpu_instancing",
        "KHR_lights_punctual",
        "EXT_lights_image_based",
        "KHR_animation_pointer",
        "KHR_xmp_json_ld",
        "KHR_techniques_webgl",
        "MSFT_lod",
    }
)
_UNREAD_FAMILY = re.compile(r"[A-Z0-9]+_(materials|texture)_\w+")
# A buffer of these may be a placeholder without uri (the extension's "fallback").
_MESHOPT = frozenset({"EXT_meshopt_compression", "KHR_meshopt_compression"})
MAX_EXTENSIONS = 256

_GLB_MAGIC = b"glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942


@dataclass(frozen=True, slots=True)
class _Container:
    document: dict[str, Any]
    bin_length: int | None  # None: no BIN chunk (or not a GLB)
    is_glb: bool


def read_document(data: bytes | str, *, max_bytes: int, max_json_bytes: int) -> dict[str, Any]:
    """The checked JSON document of a ``.glb`` (bytes) or ``.gltf`` (bytes or str).

    Raises:
        InvalidModel: a bad container, JSON, asset version or buffer (module docstring).
    """
    container = _container(data, max_bytes=max_bytes, max_json_bytes=max_json_bytes)
    _check_asset(container.document)
    required = _required_extensions(container.document)
    _check_buffers(container.document, container, placeholders=bool(required & _MESHOPT))
    return container.document


def _container(data: bytes | str, *, max_bytes: int, max_json_bytes: int) -> _Container:
    if isinstance(data, bytearray | memoryview):
        data = bytes(data)
    if not isinstance(data, bytes | str):
        raise InvalidModel(f"glTF must be bytes or str, got {type(data).__name__}", joint="glb")
    if len(data) > max_bytes:
        raise InvalidModel(f"the file is larger than {max_bytes} bytes", joint="glb")
    if isinstance(data, bytes) and data[:4] == _GLB_MAGIC:
        json_bytes, bin_length = _glb_chunks(data, max_json_bytes)
        return _Container(_parse_json(json_bytes), bin_length, is_glb=True)
    if isinstance(data, str):
        try:
            data = data.encode("utf-8")
        except UnicodeEncodeError:
            raise InvalidModel("the JSON is not valid Unicode", joint="json") from None
        if len(data) > max_bytes:
            raise InvalidModel(f"the file is larger than {max_bytes} bytes", joint="glb")
    return _Container(_parse_json(data), None, is_glb=False)


def _glb_chunks(data: bytes, max_json_bytes: int) -> tuple[bytes, int | None]:
    """The JSON chunk's bytes and the BIN chunk's length (glTF 2.0 spec 4.4)."""
    size = len(data)
    if size < 12:
        raise InvalidModel(f"truncated: {size} bytes, the GLB header alone has 12", joint="glb")
    _, version, length = struct.unpack_from("<4sII", data, 0)
    if version != 2:
        raise InvalidModel(f"GLB version {version} is not supported (2 is)", joint="glb")
    if length > size:
        raise InvalidModel(
            f"truncated: the header declares {length} bytes, the file has {size}",
            joint="glb",
            field="length",
        )
    if length < size:
        raise InvalidModel(
            f"the header declares {length} bytes but the file has {size}",
            joint="glb",
            field="length",
        )
    json_bytes: bytes | None = None
    bin_length: int | None = None
    offset, index = 12, 0
    while offset < length:
        if length - offset < 8:
            raise InvalidModel(
                f"truncated: chunk {index} header needs 8 bytes, {length - offset} remain",
                joint="glb",
                field=f"chunks[{index}]",
            )
        chunk_length, chunk_type = struct.unpack_from("<II", data, offset)
        start = offset + 8
        if chunk_length > length - start:
            raise InvalidModel(
                f"truncated: chunk {index} declares {chunk_length} bytes, {length - start} remain",
                joint="glb",
                field=f"chunks[{index}]",
            )
        if index == 0:
            if chunk_type != _CHUNK_JSON:
                raise InvalidModel("the first chunk must be JSON", joint="glb", field="chunks[0]")
            if chunk_length > max_json_bytes:
                raise InvalidModel(
                    f"the JSON chunk is larger than {max_json_bytes} bytes",
                    joint="glb",
                    field="chunks[0]",
                )
            json_bytes = data[start : start + chunk_length]
        elif chunk_type == _CHUNK_JSON:
            raise InvalidModel("a second JSON chunk", joint="glb", field=f"chunks[{index}]")
        elif chunk_type == _CHUNK_BIN:
            if index != 1:
                raise InvalidModel(
                    "the BIN chunk must be the second chunk", joint="glb", field=f"chunks[{index}]"
                )
            bin_length = chunk_length
        offset = start + chunk_length
        index += 1
    if json_bytes is None:
        raise InvalidModel("truncated: no JSON chunk", joint="glb", field="chunks[0]")
    return json_bytes, bin_length


def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not JSON")


def _parse_json(raw: bytes) -> dict[str, Any]:
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise InvalidModel(f"the JSON is not UTF-8 ({e.reason})", joint="json") from None
    try:
        doc = json.loads(text, parse_constant=_reject_constant)
    except RecursionError:
        raise InvalidModel("the JSON is nested too deeply", joint="json") from None
    except ValueError as e:  # JSONDecodeError, NaN/Infinity, integers over 4300 digits
        raise InvalidModel(f"the JSON is not valid: {e}", joint="json") from None
    if not isinstance(doc, dict):
        raise InvalidModel("the JSON document must be an object", joint="json")
    return doc


def _check_asset(doc: dict[str, Any]) -> None:
    asset = doc.get("asset")
    version = asset.get("version") if isinstance(asset, dict) else None
    if not isinstance(version, str):
        raise InvalidModel("asset.version is missing", joint="asset", field="version")
    if not version.startswith("2."):
        raise InvalidModel(
            f"glTF {version} is not supported (2.x is)", joint="asset", field="version"
        )


def _required_extensions(doc: dict[str, Any]) -> set[str]:
    """``extensionsRequired``, refused if one of them may change the nodes or skins."""
    names = json_array(doc, "extensionsRequired", "json", max_len=MAX_EXTENSIONS, what="extensions")
    if not all(isinstance(n, str) for n in names):
        raise InvalidModel(
            "extensionsRequired must be an array of strings",
            joint="json",
            field="extensionsRequired",
        )
    unknown = [n for n in names if n not in REQUIRED_BUT_UNREAD and not _UNREAD_FAMILY.fullmatch(n)]
    if unknown:
        raise InvalidModel(
            f"the file requires {', '.join(repr(n[:64]) for n in unknown[:5])}, an extension "
            "this reader does not know: it may change the nodes or skins, so the skeleton "
            "cannot be read without it (the mesh, material and texture extensions, such as "
            "KHR_draco_mesh_compression or EXT_meshopt_compression, are accepted)",
            joint="json",
            field="extensionsRequired",
        )
    return set(names)


def _check_buffers(doc: dict[str, Any], container: _Container, *, placeholders: bool) -> None:
    buffers = json_array(doc, "buffers", "json", max_len=MAX_BUFFERS, what="buffers")
    for i, buf in enumerate(buffers):
        part = f"buffers[{i}]"
        if not isinstance(buf, dict):
            raise InvalidModel("a buffer must be a JSON object", joint=part)
        declared = buf.get("byteLength")
        if type(declared) is not int or declared < 1:
            raise InvalidModel(
                f"byteLength must be an integer >= 1, got {declared!r}",
                joint=part,
                field="byteLength",
            )
        uri = buf.get("uri")
        if uri is None and (not container.is_glb or i != 0):
            if placeholders:  # meshopt's placeholder: never loaded (its spec, "Fallback")
                continue
            raise InvalidModel(
                "only the first buffer of a .glb may omit uri (it is the BIN chunk), or a "
                "placeholder buffer of a file that requires EXT_meshopt_compression",
                joint=part,
                field="uri",
            )
        if uri is None:
            available = container.bin_length
            if available is None or declared > available:
                raise InvalidModel(
                    f"declares {declared} bytes, the BIN chunk holds {available or 0}",
                    joint=part,
                    field="byteLength",
                )
        elif not isinstance(uri, str):
            raise InvalidModel("uri must be a string", joint=part, field="uri")
        elif uri.startswith("data:"):
            held = _data_uri_length(uri, part)
            if declared > held:
                raise InvalidModel(
                    f"declares {declared} bytes, its data URI holds {held}",
                    joint=part,
                    field="byteLength",
                )


def _data_uri_length(uri: str, part: str) -> int:
    header, sep, payload = uri.partition(",")
    if not sep or not header.endswith(";base64"):
        raise InvalidModel(
            "a data URI must be base64 (data:...;base64,...)", joint=part, field="uri"
        )
    try:
        return len(base64.b64decode(payload, validate=True))
    except (binascii.Error, ValueError):
        raise InvalidModel("the data URI is not valid base64", joint=part, field="uri") from None


def json_array(doc: dict[str, Any], key: str, part: str, *, max_len: int, what: str) -> list[Any]:
    """``doc[key]`` (an empty list when absent), refused unless an array of at most
    ``max_len`` items; errors name ``part`` and ``key``, and count ``what``."""
    value = doc.get(key, [])
    if not isinstance(value, list):
        raise InvalidModel(f"{key} must be an array", joint=part, field=key)
    if len(value) > max_len:
        raise InvalidModel(f"too many {what}: {len(value)} > {max_len}", joint=part, field=key)
    return value
