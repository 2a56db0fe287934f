"""The robots and tasks behind the ports: a simulated robot of any description
(`simulated`), the kitchen task (`kitchen`), a recorded robot and task (`recorded`)."""
