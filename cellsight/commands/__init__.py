"""The ``cellsight`` sub-commands, one module each. Every command module, here or in the tool
package it drives (``cellsight.sweep.command``, ...), has one ``register(sub)`` that adds its
parser to the sub-commands and sets ``func`` to the function that runs it (``args -> exit
status``); :data:`cellsight.cli.COMMANDS` lists them in ``--help`` order. Modules here import
their heavy parts where used, so that ``cellsight --help`` stays quick."""
