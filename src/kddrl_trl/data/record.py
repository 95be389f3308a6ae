"""``python -m kddrl_trl.data.record``: the former path of the entry point :mod:`kddrl_trl.record`, kept working."""

from kddrl_trl.record import main

if __name__ == "__main__":
    main()
