"""The `dsteleop` command line: the dispatcher (`main`), one module per sub-command, the
options they share (`options`) and the composition root that wires a loop (`compose`)."""
