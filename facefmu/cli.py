"""The `facefmu` command line."""

import argparse
import sys


def main(argv=None):
    parser = argparse.ArgumentParser(prog="facefmu", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("version", help="print the version")
    args = parser.parse_args(argv)
    if args.command == "version":
        import solver
        print(solver.__version__)
    return 0


if __name__ == "__main__":
    sys.exit(main())
