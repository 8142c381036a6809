"""From a researcher's folder of renders to a stimulus set: mapping files to scenes, methods
and levels (:mod:`.mapping`), probing and decoding them (:mod:`.probe`), and writing the
study's copies and manifest (:mod:`.build`). The player's own rules about what it can show
are applied by ``study_app.study_init``, which drives these steps."""
