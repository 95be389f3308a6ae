"""``python -m kddrl_trl.data.prepare``: the former path of the entry point :mod:`kddrl_trl.prepare`, kept working."""

from kddrl_trl.prepare import main

if __name__ == "__main__":
    main()
