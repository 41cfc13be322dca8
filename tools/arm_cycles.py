"""Bounds on the Cortex-M4 cycles of executed Thumb-2 code, at zero wait states.

tools/bench_arm.py counts instructions. What they cost in cycles depends on the kind of
each instruction and on what runs next to it; this module bounds that from the processor's
instruction timings (Cortex-M4 Technical Reference Manual, "Table of processor
instructions", cycle counts for a system with zero wait states):

- most instructions take 1 cycle, the Cortex-M4's multiplies too (MUL, MLA, MLS and the
  64-bit SMULL, UMULL, SMLAL, UMLAL);
- a single load or store (LDR, STR and their byte, halfword and exclusive forms) 2, or 1
  where neighbouring single loads and stores pipeline their address and data phases; one
  whose address depends on the instruction just before stalls a cycle more;
- LDRD, STRD, LDM, STM, PUSH and POP of N registers 1 + N (they do not pipeline);
- SDIV and UDIV 2 to 12, as the operands' sizes let the division end early;
- TBB and TBH a load (2) and an add (1), then the branch's refill;
- a taken branch, or any other write of the PC (POP {..., pc}, BX LR), adds the pipeline
  refill P, 1 to 3 cycles (the target's alignment and width, and whether the address was
  speculated early);
- an instruction that an IT block skips still takes its issue cycle.

The lower bound takes each instruction at its least: stores 1, a load 1 after another
single load or store and 2 otherwise, divisions 2, refills 1, an instruction inside an IT
block 1 (it may be skipped). The upper bound takes each at its most: single loads and
stores 3 (the address stall), LDRD, STRD and the multiple transfers 2 + N, divisions 12,
refills 3. Neither counts flash wait states: on the STM32F407 at 168 MHz (5 wait states)
the ART accelerator's prefetch buffer and 1 KiB instruction cache (RM0090, 3.5.2) hide them
for straight code and loops that stay in the cache, and a taken branch to a line not in it
waits for the flash. The DWT cycle counter on the board (STATUS's filter_cycles) is the
measurement; these bounds say what to expect of it.
"""
from __future__ import annotations

import re

_CONDITION = "(eq|ne|cs|hs|cc|lo|mi|pl|vs|vc|hi|ls|ge|lt|gt|le|al)?"
_SINGLE_LOAD = re.compile(rf"^ldr(b|h|sb|sh|ex|exb|exh)?{_CONDITION}$")
_SINGLE_STORE = re.compile(rf"^str(b|h|ex|exb|exh)?{_CONDITION}$")
_DOUBLE = re.compile(rf"^(ldr|str)d{_CONDITION}$")
_MULTIPLE = re.compile(rf"^((ldm|stm)(ia|db|fd|ea)?|push|pop){_CONDITION}$")
_DIVIDE = re.compile(rf"^[su]div{_CONDITION}$")
_TABLE_BRANCH = re.compile(rf"^tb[bh]{_CONDITION}$")
_IT = re.compile(r"^it[te]{0,3}$")

#: The pipeline refill P of a taken branch, least and most.
REFILL = (1, 3)


def register_count(operands: str) -> int:
    """Registers in an operand such as "{r4, r5, r6, lr}" or "sp!, {r4-r7, lr}"."""
    count = 0
    for item in operands[operands.index("{") + 1: operands.index("}")].split(","):
        first, _, last = item.strip().partition("-")
        count += int(last[1:]) - int(first[1:]) + 1 if last else 1
    return count


def _kind(mnemonic: str) -> str:
    m = mnemonic.split(".")[0]  # the .w and .n width suffixes
    for kind, pattern in (("load", _SINGLE_LOAD), ("store", _SINGLE_STORE), ("double", _DOUBLE),
                          ("multiple", _MULTIPLE), ("divide", _DIVIDE), ("table", _TABLE_BRANCH), ("it", _IT)):
        if pattern.match(m):
            return kind
    return "other"


def block_cycles(instructions: list[tuple[str, str]]) -> tuple[int, int]:
    """(least, most) cycles of a straight run of instructions, each (mnemonic, operands) as
    objdump prints them, without the refill of a branch that ends it (the caller counts
    refills where execution jumps)."""
    low = high = 0
    it_left = 0         # instructions still covered by the last IT
    after_access = False  # the previous instruction was a single load or store
    for mnemonic, operands in instructions:
        kind = _kind(mnemonic)
        covered = it_left > 0
        it_left = max(it_left - 1, 0)
        if kind == "load":
            least, most = (1 if after_access else 2), 3
        elif kind == "store":
            least, most = 1, 3
        elif kind == "double":
            least, most = 3, 4
        elif kind == "multiple":
            n = register_count(operands)
            least, most = 1 + n, 2 + n
        elif kind == "divide":
            least, most = 2, 12
        elif kind == "table":
            least, most = 3, 4
        else:
            least = most = 1
            if kind == "it":
                it_left = len(mnemonic.split(".")[0]) - 1
        low += 1 if covered else least
        high += most
        after_access = kind in ("load", "store")
    return low, high
