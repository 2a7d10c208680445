"""The ``storyteller`` command: thin typer commands that parse options and call the session,
planning and llm packages. Nothing imports from here.
"""
