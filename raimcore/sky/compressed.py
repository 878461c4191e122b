"""The bytes of a RINEX file, compressed or not: one opener for every RINEX reader.

IGS and national archives publish RINEX compressed, often twice: Hatanaka (Compact RINEX,
``.crx`` / ``.yyd``) for observations, then gzip (``.gz``) or Unix compress (``.Z``). This
module undoes both layers so that :func:`raimcore.sky.rinex.read_obs` and
:func:`~raimcore.sky.rinex.read_nav` only ever see plain RINEX text.

Formats, recognised by their leading magic bytes, whatever the file's name (archives do
mislabel gzip as ``.Z``); the name only serves to word the error when a file named like an
archive holds neither an archive nor RINEX:

========================  =================  ================================================
container                 magic              decompressed by
========================  =================  ================================================
gzip ``.gz``              ``1f 8b``          :mod:`gzip` (standard library)
Unix compress ``.Z``      ``1f 9d``          the ``hatanaka`` package (LZW via ``ncompress``)
zip ``.zip``              ``PK 03 04``       :mod:`zipfile`; exactly one member
bzip2 ``.bz2``            ``BZh``            :mod:`bz2` (standard library)
========================  =================  ================================================

then, inside or alone, Compact RINEX 1.0 / 3.0 (first line labelled ``CRINEX VERS / TYPE``,
suffix ``.crx`` or ``.yyd``), restored with ``hatanaka.crx2rnx`` (Y. Hatanaka's own
``CRX2RNX`` program, shipped compiled in the package). So ``.crx.gz``, ``.yyd.Z``,
``.crx.Z``, ``.rnx.gz`` and ``.zip`` of any of them are read directly.

``hatanaka`` is imported only when a ``.Z`` or Compact RINEX file is met (it costs ~40 ms to
import and starts a subprocess).

References
----------
Hatanaka, Y. (2008) A Compression Format and Tools for GNSS Observation Data, Bulletin of
the Geographical Survey Institute 55. RFC 1952 (gzip). PKWARE APPNOTE 6.3 (zip).
"""

from __future__ import annotations

import bz2
import gzip
import io
import warnings
import zipfile
import zlib
from pathlib import Path

__all__ = ["RinexError", "read_bytes"]


class RinexError(ValueError):
    """A malformed, truncated or unreadable RINEX file: names the file, the line (1-based,
    when there is one) and what was expected.

    Defined here, the lowest layer of the RINEX readers, and re-exported by
    :mod:`raimcore.sky.rinex`.
    """

    def __init__(self, path, line: int | None, message: str):
        self.path = str(path)
        self.line = line
        where = f"{self.path}, line {line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")


#: (name, magic bytes, file suffixes that announce it), in the order they are tried.
_CONTAINERS = (
    ("gzip", b"\x1f\x8b", (".gz",)),
    ("Unix compress", b"\x1f\x9d", (".z",)),
    ("zip", b"PK\x03\x04", (".zip",)),
    ("bzip2", b"BZh", (".bz2",)),
)


#: The label of the first line of RINEX and of Compact RINEX.
_FIRST_LABELS = (b"RINEX VERSION / TYPE", b"CRINEX VERS   / TYPE")


def read_bytes(path) -> bytes:
    """The plain RINEX text of ``path``, decompressed as its magic bytes say.

    Parameters
    ----------
    path : str or os.PathLike
        A RINEX file, plain or compressed (see the module docstring for the formats).

    Returns
    -------
    bytes
        The file's content after removing the container (gzip, ``.Z``, zip, bzip2) and the
        Hatanaka compression, if any. Plain files are returned unchanged.

    Raises
    ------
    RinexError (a ValueError), naming the file, when the file does not exist, a container
    is corrupt or truncated, a zip archive does not hold exactly one file, a file named
    like an archive holds neither an archive nor RINEX, or the Hatanaka decompression
    fails or skips damaged epochs. Whether the result is RINEX is checked by the reader
    (its header line).
    """
    p = Path(path)
    if not p.is_file():
        raise RinexError(path, None, "file does not exist")
    data = p.read_bytes()
    for name, magic, _ in _CONTAINERS:
        if data.startswith(magic):
            data = _unpack(path, name, data)
            break
    else:
        suffix = p.suffix.lower()
        for name, _, suffixes in _CONTAINERS:
            if suffix in suffixes and data[60:80].rstrip() not in _FIRST_LABELS:
                raise RinexError(path, None, f"expected a {name} archive (the name ends in "
                                 f"'{p.suffix}'), the content is neither that nor RINEX")
    if _is_compact_rinex(data):
        data = _crx2rnx(path, data)
    return data


def _unpack(path, name: str, data: bytes) -> bytes:
    try:
        if name == "gzip":
            return gzip.decompress(data)
        if name == "bzip2":
            return bz2.decompress(data)
        if name == "zip":
            with zipfile.ZipFile(io.BytesIO(data)) as z:
                members = [m for m in z.infolist() if not m.is_dir()]
                if len(members) != 1:
                    listed = ", ".join(m.filename for m in members[:4])
                    more = ", ..." if len(members) > 4 else ""
                    raise RinexError(path, None, "expected a zip archive holding one RINEX "
                                     f"file, it holds {len(members)} ({listed}{more})")
                return z.read(members[0])
        import hatanaka

        # Unix compress (LZW). hatanaka.decompress also restores a Compact RINEX member,
        # which read_bytes then finds already plain.
        return hatanaka.decompress(data)
    except RinexError:
        raise
    except (OSError, EOFError, zlib.error, ValueError, RuntimeError, zipfile.BadZipFile,
            NotImplementedError) as exc:
        raise RinexError(path, None, f"corrupt or truncated {name} archive "
                         f"({_one_line(exc)})") from None


def _is_compact_rinex(data: bytes) -> bool:
    return data[60:80].startswith(b"CRINEX VERS") or b"COMPACT RINEX" in data[:80]


def _crx2rnx(path, data: bytes) -> bytes:
    """CRX2RNX, its warnings refused too: it warns when it skips damaged epochs, and a
    reader that silently lost epochs would be worse than one that stops."""
    import hatanaka

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            return hatanaka.crx2rnx(data)
    except (RuntimeError, ValueError, UserWarning) as exc:  # HatanakaException: RuntimeError
        raise RinexError(path, None, "expected Compact RINEX (Hatanaka) content that "
                         f"decompresses, got: {_one_line(exc)}") from None


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 160 else text[:157] + "..."
