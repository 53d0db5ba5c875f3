"""The CAD mini library: parametric CAD models and the code that builds the library folder.

``catalog.MODELS`` lists the shipped models; ``build.build_library`` writes the folder that
``cadnerf_core.library.format.load_library`` reads; ``importer`` adds users' CAD files;
``cli`` holds the ``cadnerf library`` commands.
"""
