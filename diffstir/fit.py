"""``python -m diffstir.fit recording=PATH out=DIR``: the same as ``diffstir-fit``."""

from diffstir.apps.fit import main

if __name__ == "__main__":
    main()
