"""`vrsim replay LOG [--scenario FILE] [--machine FILE] [--prescription MAP] [--layer NAME]
[--product NAME] [--rate-field F] [--target-field F] [--unit U] [--session N ...] [--start-s S]
[--end-s S] [--out DIR] [--json]`: a machine's as-applied log replayed through the simulated machine
(`services.sim.replay`), the twin's rates against the logged ones."""

from __future__ import annotations

HELP = "replay an as-applied log through the simulated machine: the twin's rates against the logged ones"


def configure(parser) -> None:
    from vrsim.services.cli.log_options import add_log_options

    add_log_options(parser)
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    parser.add_argument("--out", metavar="DIR",
                        help="also write replay.parquet, replay.png, replay_map.png and summary.json "
                             "into DIR")


def run(args) -> int:
    from dataclasses import replace

    from vrsim.services.cli.log_options import replay_input
    from vrsim.services.outputs.encode import dumps_text
    from vrsim.services.outputs.replay import text_replay, write_replay
    from vrsim.services.sim.replay import replay_records

    records, scenario, extra = replay_input(args, args.log)
    rp = replay_records(records, scenario)
    rp = replace(rp, summary={**rp.summary, **extra})
    if args.out:
        write_replay(rp, args.out)
    if args.json:
        print(dumps_text({**rp.summary, "out_dir": args.out} if args.out else rp.summary, indent=True))
    else:
        print(text_replay(rp))
        if args.out:
            print(f"  outputs in {args.out}/ (replay.parquet, replay.png, replay_map.png, summary.json)")
    return 0
