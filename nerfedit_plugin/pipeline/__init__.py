"""The stages a user runs, end to end, and the folders they read and write: ``train`` (:mod:`.train` → a run
folder, :mod:`.run`), ``extract`` (:mod:`.extract`), ``edit`` (:mod:`.edit` → an edit folder), ``render``
(:mod:`.render` → a render folder; :mod:`.executors` run its shots here or on Ray), ``eval`` (:mod:`.evaluate`) and
the ``demo`` chaining them (:mod:`.demo`). The command line (:mod:`nerfedit_plugin.cli`) parses arguments and calls
these."""
