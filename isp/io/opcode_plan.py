"""Which DNG opcodes the pipeline applies, where, and which it skips (and why).

One table, read by the stages that apply opcodes and by ``isp info``, so
that what is reported is what happens. Every opcode of a file is either
applied by the decoder, applied by a named stage, or listed as skipped with
the reason it cannot be applied; none is dropped silently.

DNG 1.7.1.0, chapter 7: OpcodeList1 applies to the stored raw values,
OpcodeList2 to the linearised mosaic, OpcodeList3 to the demosaiced image.
``black_level`` applies OpcodeList2's value maps (MapPolynomial, MapTable)
with the linearisation, ``lens_shading`` the gain maps (GainMap,
FixVignetteRadial) of lists 2 and 3; the stages ``opcode_list1``,
``opcode_list2`` and ``opcode_list3`` apply everything else of their list
(:mod:`modules.opcode_lists`). An opcode is skipped only where it cannot be
applied: an unknown or vendor ID, or one the image cannot take (a bad-pixel
opcode on a three-plane image, a warp whose plane count does not fit), as
the opcode's :meth:`~isp.opcodes.Opcode.unsupported` says.
"""

from __future__ import annotations

from dataclasses import dataclass

from isp.meta import CameraMeta

#: (opcode list, opcode name) -> the stage that applies it, for the opcodes
#: a stage other than the list's own applies
HANDLERS: dict[tuple[int, str], str] = {
    (2, "MapPolynomial"): "black_level",
    (2, "MapTable"): "black_level",
    (2, "GainMap"): "lens_shading",
    (2, "FixVignetteRadial"): "lens_shading",
    (3, "GainMap"): "lens_shading",
    (3, "FixVignetteRadial"): "lens_shading",
}

#: opcode list -> the stage that applies the rest of it
LIST_STAGES: dict[int, str] = {1: "opcode_list1", 2: "opcode_list2", 3: "opcode_list3"}

_WHEN = {1: "on the stored raw values, before black_level",
         2: "on the linear mosaic, after black_level and before lens_shading",
         3: "on camera RGB, after demosaic"}


@dataclass(frozen=True)
class PlannedOpcode:
    """What happens to one opcode of a file.

    Attributes
    ----------
    list_no : int
        1, 2 or 3 (OpcodeList1/2/3).
    index : int
        0-based position in its list.
    name : str
        The opcode's name (``Unknown(ID)`` for IDs the reader does not know).
    action : str
        ``"decoder"``, the name of the stage that applies it, or
        ``"skipped"``.
    reason : str
        Why, in words.
    optional : bool
        The opcode's flag bit 0: a reader that cannot apply it may skip it.
    """

    list_no: int
    index: int
    name: str
    action: str
    reason: str
    optional: bool

    def as_dict(self) -> dict:
        """JSON-ready form (as ``isp info`` prints it)."""
        return {"list": f"OpcodeList{self.list_no}", "index": self.index, "opcode": self.name,
                "action": self.action, "reason": self.reason, "optional": self.optional}


def decoder_applied(meta: CameraMeta, list_no: int, index: int, name: str) -> bool:
    """True if LibRaw already applied opcode ``index`` of list ``list_no``."""
    return f"OpcodeList{list_no}[{index}] {name}" in meta.applied_by_decoder


def image_planes(meta: CameraMeta, list_no: int) -> int:
    """Planes of the image OpcodeList ``list_no`` applies to: 1 for a CFA
    mosaic before demosaicing, 3 after it and for a linear DNG."""
    return 1 if (meta.cfa is not None and list_no in (1, 2)) else 3


def opcode_plan(meta: CameraMeta) -> list[PlannedOpcode]:
    """Every opcode of ``meta`` with what the default pipeline does with it."""
    out = []
    for list_no in sorted(meta.opcodes):
        for i, op in enumerate(meta.opcodes[list_no]):
            name = op.name
            optional = bool(getattr(op, "optional", False))
            if decoder_applied(meta, list_no, i, name):
                out.append(PlannedOpcode(list_no, i, name, "decoder",
                                         "applied by LibRaw while decoding", optional))
                continue
            stage = HANDLERS.get((list_no, name))
            if stage is not None:
                reason = f"applied by the {stage} stage"
                if list_no == 3 and meta.cfa is not None:
                    reason += (" before demosaic, per CFA colour (gains vary slowly, so the "
                               "order does not matter)")
                out.append(PlannedOpcode(list_no, i, name, stage, reason, optional))
                continue
            why = op.unsupported(list_no, image_planes(meta, list_no))
            if why is None:
                stage = LIST_STAGES[list_no]
                out.append(PlannedOpcode(list_no, i, name, stage,
                                         f"applied by the {stage} stage, {_WHEN[list_no]}",
                                         optional))
                continue
            if not optional:
                why += "; the file marks it required, so the render differs from Adobe's"
            out.append(PlannedOpcode(list_no, i, name, "skipped", why, optional))
    return out


def handled_by(meta: CameraMeta, stage: str) -> list[tuple[int, int, object]]:
    """(list_no, index, opcode) the stage named ``stage`` must apply, in
    list order."""
    return [(p.list_no, p.index, meta.opcodes[p.list_no][p.index])
            for p in opcode_plan(meta) if p.action == stage]
