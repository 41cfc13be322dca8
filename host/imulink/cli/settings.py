"""`imulink settings`."""
from __future__ import annotations

from imulink import core, hil, protocol
from imulink.board.link import DEFAULT_BAUD, Link
from imulink.cli.common import (
    PORT_HELP,
    UsageError,
    assignments_of,
    baud_rate,
    json_argument,
    one_line_errors,
    place_arguments,
    print_json,
    text_columns,
)
from imulink.io import settings_file
from imulink.io.files import check_output


@one_line_errors
def run(args) -> int:
    wanted = assignments_of(args.assignments)
    if args.save:
        check_output(args.save)
    loaded = settings_file.load(args.load) if args.load else None
    if loaded is not None and args.filter is not None and args.filter != loaded.filter_name:
        raise UsageError(f"{args.load} holds {loaded.filter_name} settings; --filter {args.filter} contradicts it")
    changed = set()
    with Link(args.port, args.baud) as link:
        link.connect()
        if loaded is not None:
            hil.apply_settings(link, loaded)
            changed |= set(loaded.values)
        elif args.filter is not None:
            link.command("SELECT_FILTER", filter_id=core.BOARD_FILTERS[args.filter][0])
        filter_id, board = hil.read_settings(link)
        by_name = {s["name"]: (index, s) for index, s in board.items()}
        unknown = [name for name in wanted if name not in by_name]
        if unknown:
            raise UsageError(f"the board's {core.filter_name_of(filter_id)} has no setting {', '.join(unknown)}; "
                             f"it has {', '.join(by_name)}")
        for name, value in wanted.items():  # in the board's own formats and ranges (its SETTING answers)
            index, setting = by_name[name]
            low, high = hil.setting_range(setting)
            if not low <= value <= high:
                raise UsageError(f"{name} = {value:g} {setting['unit']} is outside the board's range "
                                 f"{hil.setting_range_text(setting)}"
                                 + ("; nothing was set" if not changed else "; nothing after it was set"))
            try:
                link.command("SET_SETTING", index=index, value=core.to_fixed(value, setting["frac_bits"], name))
            except protocol.CommandError as exc:
                raise hil.HilError(f"the board refuses {name} = {value:g} {setting['unit']} ({exc.reason}); "
                                   "nothing after it was set") from None
            changed.add(name)
        if changed:
            filter_id, board = hil.read_settings(link)  # read back: what the board now runs with
    name = core.filter_name_of(filter_id)
    rows = [{"name": s["name"], "value": s["value"] / 2.0 ** s["frac_bits"], "raw": s["value"], "unit": s["unit"],
             "frac_bits": s["frac_bits"], "min": hil.setting_range(s)[0], "max": hil.setting_range(s)[1],
             "range": hil.setting_range_text(s), "changed": s["name"] in changed} for s in board.values()]
    if args.save:
        values = {r["name"]: r["value"] for r in rows if r["name"] != "sample_rate"}
        settings_file.save(settings_file.FilterSettings(name, values), args.save)
    if args.json:
        print_json({"port": args.port, "filter": name, "settings": rows, "saved_to": args.save})
        return 0
    print(f"{args.port}: filter {name}" + (" (settings read back after the change)" if changed else ""))
    print(text_columns([(f"  {r['name']}", f"{r['value']:.6g}", r["unit"], r["range"],
                     f"Q{r['frac_bits']}", "changed" if r["changed"] else "") for r in rows]))
    if args.save:
        print(f"settings file: {args.save} ({name}, every setting but sample_rate)")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser(
        "settings", help="a board's filter settings: list them, set some by name, keep them in a file",
        description="Read the active filter's settings from the board (its own table: names, units, fixed-point "
                    "formats) and print them in SI units. NAME=VALUE arguments set settings first (SET_SETTING in "
                    "the board's format, then all are read back; the filter restarts with each), --filter makes "
                    "another filter active, --load gives the board a settings file (its filter and values), "
                    "--save writes what the board then runs with to a settings file (record, inject, emulate and "
                    "core.run take it with --settings FILE). A value the board refuses ends the command with its "
                    "reason; the settings set before it stay.")
    p.add_argument("port", metavar="PORT", help=PORT_HELP)
    p.add_argument("assignments", metavar="NAME=VALUE", nargs="*", help="settings to set, in SI units")
    p.add_argument("--filter", choices=list(core.BOARD_FILTERS), help="make this filter active first")
    p.add_argument("--load", metavar="FILE", help="give the board the settings of FILE (and make its filter active)")
    p.add_argument("--save", metavar="FILE", help="write the board's settings to FILE (a settings file)")
    p.add_argument("--baud", type=baud_rate, default=DEFAULT_BAUD,
                   help=f"line rate of a real serial port (default: {DEFAULT_BAUD}; ignored by sockets and ptys)")
    place_arguments(p)
    json_argument(p, "the filter and its settings")
    p.set_defaults(func=run)

