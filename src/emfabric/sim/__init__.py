"""The simulated system as data: ``Model`` (everything a step reads: the kernels' records and a
resolved options record), ``State`` (everything a step writes; a checkpoint is a State), the
builder (scenario → Model), the projectile's geometry and initial pose, the diagnostics of a
state (the history record, the stop rule, the plausibility guards) and the compiled-call helper.

May import: config, sources, _kernels. Never imports integrators, io, runner, studies, viz, cli.
"""
