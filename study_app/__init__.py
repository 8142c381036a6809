"""The participant's player and the experimenter's tools around a study.

The player (:mod:`.app` and the modules it names: display, pre-flight, trial and text
screens, input mapping, layout, drawing) runs one participant's session; :mod:`.remote` is
its side of a study server (download the study, upload the session as it grows). The
experimenter's tools check a study folder before it is sent out (:mod:`.study_check`), pack a
session for return (:mod:`.export`), render synthetic stimuli (:mod:`.synth`) and simulate a
panel of raters (:mod:`.simulate`).

Not here: the ``cgvq-session/1`` session file contract, the study folder and the upload wire
protocol are :mod:`session_store`; the study server and its dashboard are
:mod:`study_server`; the ``cgvq-study`` command line is :mod:`cgvq_cli`.
"""

__version__ = "0.1.0"
