"""Rebuild a finished, indexed archive from one whose writer never finished.

A recorder killed mid-run leaves an MCAP file without summary or index, maybe with a
half-written chunk at the end; a damaged disk leaves a finished file with a corrupt
chunk. Tools that seek (``make_reader``, most viewers) refuse both. Repair copies what
``bridge.archive.reader`` can read (schemas, channels, every message of every intact
chunk, metadata, attachments) into a new file with chunk index and summary, and says
what was lost.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mcap.writer import CompressionType, Writer

from bridge._text import counted
from bridge.archive.explain import describe_damage
from bridge.archive.reader import ArchiveReader
from bridge.archive.walk import read_archive
from bridge.exceptions import ArchiveError, ArchiveReadError


@dataclass(frozen=True)
class RepairReport:
    """What a repair kept and what it could not."""

    source: Path
    output: Path
    messages: int
    channels: int
    chunks: int
    dropped_bytes: int
    was_complete: bool
    problem: str | None
    damage: str = ""

    def text(self) -> str:
        """The report in words.

        Returns:
            The report, as ``gx3 repair`` prints it.
        """
        state = "was finished" if self.was_complete else f"was not finished ({self.problem})"
        return (f"{self.source} {state}: recovered {counted(self.messages, 'message')} on "
                f"{counted(self.channels, 'channel')} from {counted(self.chunks, 'chunk')}, "
                f"dropped {counted(self.dropped_bytes, 'byte')}; wrote {self.output}"
                + (f"\n{self.damage}" if self.damage else ""))


def default_output(source: Path) -> Path:
    """Where a repair writes by default: ``run.mcap`` gives ``run.repaired.mcap``.

    An archive under another name still gives an ``.mcap`` file, the name of what it is.
    """
    return source.with_name(f"{source.stem}.repaired.mcap")


def repair(source: Path, output: Path | None = None) -> RepairReport:
    """Copy the readable part of an archive into a new, finished one.

    Args:
        source: The archive to repair; it is only read.
        output: Where to write; None: ``default_output(source)``.

    Returns:
        What was kept and what could not be.

    Raises:
        ArchiveReadError: ``source`` is not an archive, holds no readable message, or
            ``output`` would overwrite it.
        ArchiveError: ``output`` cannot be written.
    """
    source = Path(source)
    output = default_output(source) if output is None else Path(output)
    archive = read_archive(source, warn=lambda _: None)
    if output.resolve() == source.resolve():
        raise ArchiveReadError(f"{output}: the output would overwrite the file being "
                               "repaired; choose another path with -o")
    if not archive.message_count:
        raise ArchiveReadError(f"{source}: no message could be recovered ("
                               + (describe_damage(archive) if archive.damage else
                                  archive.problem or "it holds none") + "); nothing written")
    try:
        with output.open("wb") as stream:
            _copy(archive, Writer(stream, compression=CompressionType.ZSTD))
    except OSError as exc:
        raise ArchiveError(f"{output}: cannot write the repaired archive "
                           f"({exc.strerror or exc}); choose a writable path") from None
    return RepairReport(source, output, archive.message_count, len(archive.channels),
                        archive.chunks, archive.dropped_bytes, archive.complete,
                        archive.problem, describe_damage(archive) if archive.damage else "")


def _copy(archive: ArchiveReader, writer: Writer) -> None:
    header = archive.header
    writer.start(header.profile if header else "", header.library if header else "")
    schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data)
                  for sid, s in archive.schemas.items()}
    channel_ids = {cid: writer.register_channel(c.topic, c.message_encoding,
                                                schema_ids.get(c.schema_id, 0), c.metadata)
                   for cid, c in archive.channels.items()}
    for meta in archive.metadata:
        writer.add_metadata(meta.name, meta.metadata)
    for att in archive.attachments:
        writer.add_attachment(att.create_time, att.log_time, att.name, att.media_type,
                              att.data)
    for block in archive.blocks:
        for ch, log, pub, seq, start, length in zip(
                block.channel.tolist(), block.log_time.tolist(), block.publish_time.tolist(),
                block.sequence.tolist(), block.start.tolist(), block.length.tolist(),
                strict=True):
            writer.add_message(channel_ids[ch], log, block.data[start : start + length],
                               pub, seq)
    writer.finish()  # type: ignore[no-untyped-call]
