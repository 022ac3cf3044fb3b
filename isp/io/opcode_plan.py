"""Which DNG opcodes the pipeline applies, where, and which it skips (and why).

One table, read by the stages that apply opcodes (``black_level``,
``lens_shading``) and by ``isp info``, so that what is reported is what
happens. Nothing is dropped silently: every opcode in a file is either
applied by the decoder, applied by a named stage, or listed as skipped with
its reason.
"""

from __future__ import annotations

from dataclasses import dataclass

from isp.meta import CameraMeta

#: (opcode list, opcode name) → stage that applies it
HANDLERS: dict[tuple[int, str], str] = {
    (2, "MapPolynomial"): "black_level",
    (2, "MapTable"): "black_level",
    (2, "GainMap"): "lens_shading",
    (2, "FixVignetteRadial"): "lens_shading",
    (3, "GainMap"): "lens_shading",
    (3, "FixVignetteRadial"): "lens_shading",
}

#: why the others are skipped
SKIP_REASONS: dict[str, str] = {
    "WarpRectilinear": "geometric distortion / lateral CA correction is not implemented",
    "WarpRectilinear2": "geometric distortion / lateral CA correction is not implemented",
    "WarpFisheye": "fisheye unwarping is not implemented",
    "FixBadPixelsConstant": "bad-pixel repair is not implemented",
    "FixBadPixelsList": "bad-pixel repair is not implemented",
    "TrimBounds": "trimming is not implemented (DefaultCrop is applied)",
    "DeltaPerRow": "per-row black corrections are not implemented",
    "DeltaPerColumn": "per-column black corrections are not implemented",
    "ScalePerRow": "per-row gain corrections are not implemented",
    "ScalePerColumn": "per-column gain corrections are not implemented",
}


@dataclass(frozen=True)
class PlannedOpcode:
    """What happens to one opcode of a file."""

    list_no: int
    index: int
    name: str
    action: str      # "decoder", a stage name, or "skipped"
    reason: str
    optional: bool

    def as_dict(self) -> dict:
        return {"list": f"OpcodeList{self.list_no}", "index": self.index, "opcode": self.name,
                "action": self.action, "reason": self.reason, "optional": self.optional}


def decoder_applied(meta: CameraMeta, list_no: int, index: int, name: str) -> bool:
    """True if LibRaw already applied opcode ``index`` of list ``list_no``."""
    return f"OpcodeList{list_no}[{index}] {name}" in meta.applied_by_decoder


def opcode_plan(meta: CameraMeta) -> list[PlannedOpcode]:
    """Every opcode of ``meta`` with what the default pipeline does with it."""
    out = []
    for list_no in sorted(meta.opcodes):
        for i, op in enumerate(meta.opcodes[list_no]):
            name = op.name
            optional = bool(getattr(op, "optional", False))
            if decoder_applied(meta, list_no, i, name):
                out.append(PlannedOpcode(list_no, i, name, "decoder", "applied by LibRaw while decoding", optional))
            elif (list_no, name) in HANDLERS:
                stage = HANDLERS[(list_no, name)]
                reason = f"applied by the {stage} stage"
                if list_no == 3 and meta.cfa is not None:
                    reason += " before demosaic, per CFA colour (gains vary slowly, so the order does not matter)"
                out.append(PlannedOpcode(list_no, i, name, stage, reason, optional))
            else:
                reason = SKIP_REASONS.get(name, "unknown or vendor opcode")
                if list_no == 1 and name not in SKIP_REASONS:
                    reason = "OpcodeList1 (stored-value) operations are not implemented"
                if not optional:
                    reason += "; the file marks it required, so the render differs from Adobe's"
                out.append(PlannedOpcode(list_no, i, name, "skipped", reason, optional))
    return out


def handled_by(meta: CameraMeta, stage: str) -> list[tuple[int, int, object]]:
    """(list_no, index, opcode) the stage named ``stage`` must apply."""
    return [(p.list_no, p.index, meta.opcodes[p.list_no][p.index])
            for p in opcode_plan(meta) if p.action == stage]


def area_slices(top: int, left: int, bottom: int, right: int, row_pitch: int, col_pitch: int,
                origin: tuple[int, int], shape: tuple[int, ...]) -> tuple[slice, slice] | None:
    """Slices of a frame's data covered by an opcode area.

    Opcode areas (DNG spec 7, "AreaSpec") are in active-area pixels and
    step by RowPitch/ColPitch from Top/Left; a frame's data starts at
    ``origin`` (its DefaultCrop offset). Returns ``(rows, cols)`` slices into
    the data, or None if the area misses it.

    >>> area_slices(1, 0, 10, 10, 2, 2, (2, 2), (6, 6))
    (slice(1, 6, 2), slice(0, 6, 2))
    >>> area_slices(0, 0, 0, 0, 1, 1, (0, 0), (4, 4))   # empty = whole image
    (slice(0, 4, 1), slice(0, 4, 1))
    """
    oy, ox = origin
    h, w = shape[0], shape[1]
    if bottom <= top or right <= left:  # an empty area means the whole image (DNG SDK)
        top, left, bottom, right, row_pitch, col_pitch = 0, 0, oy + h, ox + w, 1, 1

    def one(start, stop, pitch, off, n):
        pitch = max(1, int(pitch))
        if start < off:
            start += -(-(off - start) // pitch) * pitch
        stop = min(stop, off + n)
        if start >= stop:
            return None
        return slice(start - off, stop - off, pitch)

    rs = one(top, bottom, row_pitch, oy, h)
    cs = one(left, right, col_pitch, ox, w)
    if rs is None or cs is None:
        return None
    return rs, cs
