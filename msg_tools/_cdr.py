"""CDR encoders and decoders built from ``ros2msg`` schema texts (the one place that touches mcap_ros2).

Decoding uses mcap_ros2's public :class:`mcap_ros2.decoder.DecoderFactory`.
Encoding a single message to bytes has no public API in mcap_ros2 (its
:class:`~mcap_ros2.writer.Writer` encodes only into a file), so
:func:`encoder_for` uses ``mcap_ros2._dynamic.serialize_dynamic``, the
function that writer calls. This module isolates that workaround;
``tests/test_msg_tools_cdr.py`` pins its behaviour (exact bytes of known
messages, zero padding), so an mcap_ros2 upgrade that changes it fails there.
"""

from __future__ import annotations

from typing import Any, Callable

from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory

__all__ = ["decoder_for", "encoder_for"]


def decoder_for(type_name: str, schema_text: str) -> Callable[[bytes], Any]:
    """A function decoding CDR bytes (with encapsulation header) of ``type_name`` into an object.

    Raises
    ------
    Exception
        Whatever mcap_ros2 raises for a schema it cannot parse (callers wrap it).
    """
    schema = Schema(id=1, name=type_name, encoding="ros2msg", data=schema_text.encode("utf-8"))
    decoder = DecoderFactory().decoder_for("cdr", schema)
    if decoder is None:  # pragma: no cover - only for non-cdr / non-ros2msg input
        raise ValueError(f"no CDR decoder for {type_name}")
    return decoder


def encoder_for(type_name: str, schema_text: str) -> Callable[[Any], bytes]:
    """A function encoding an object (attributes or dict-like namespace) of ``type_name`` to CDR.

    Little endian, encapsulation header ``00 01 00 00``, padding bytes zero.
    """
    from mcap_ros2._dynamic import serialize_dynamic  # no public equivalent; see module doc

    return serialize_dynamic(type_name, schema_text)[type_name]
