"""`imulink filters`."""
from __future__ import annotations

from imulink import core
from imulink.cli.common import (
    json_argument,
    one_line_errors,
    parse_filters,
    print_json,
    text_columns,
)


@one_line_errors
def run(args) -> int:
    report: dict[str, list[dict]] = {"filters": []}
    for name in parse_filters(args.filters, core.BOARD_FILTERS):
        defaults = core.default_settings(name)
        fields = core.settings_fields(name)
        report["filters"].append({"filter": name, "settings": [
            {"name": f.name, "default": defaults[f.name], "unit": f.unit, "frac_bits": f.frac_bits} for f in fields]})
        if args.json:
            continue
        print(f"{name}:")
        print(text_columns([(f"  {f.name}", f"{defaults[f.name]:.6g}", f.unit, f"(fixed: Q{f.frac_bits})")
                        for f in fields]))
    if args.json:
        print_json(report)
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("filters", help="list the filters and their default settings",
                       description="List each filter's settings: default value, SI unit and fixed-point format.")
    p.add_argument("--filters", default="all", help="comma-separated filter names (default: all)")
    json_argument(p, "the settings")
    p.set_defaults(func=run)

