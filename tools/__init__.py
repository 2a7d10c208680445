"""What the LLM roles see and call: scene graph, region clusters, the spatial API, areas and
position sampling, and the sandbox that runs ``parse_event()`` programs.

Imports only ``sim`` (and libraries); pure: no LLM, no clock except the sandbox budget's
injected one, no network. Every error meant for an LLM is a typed ``storyteller.tools.errors`` exception
whose text can be fed back as it is.
"""
