"""The paper's simulation study: the pure computation (`core`), running it over processes
(`run`), its report (`report`) and its figures (`figures`); `dsteleop sim` is app/cli/sim.py."""
