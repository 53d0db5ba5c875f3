"""The ``cadnerf`` command: composes the commands of the core, the library and the service.

It is the one place that knows all packages; each command imports what it needs lazily, so
``cadnerf --help`` stays fast and pulls in neither torch nor the web stack.
"""
