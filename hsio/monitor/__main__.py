"""`python -m hsio.monitor RUN_DIR`: the same as `hsio monitor RUN_DIR` (how `hsio run --monitor`
starts its monitor process)."""

from hsio.commands.monitor import monitor

if __name__ == "__main__":
    monitor(prog_name="hsio monitor")
