"""A recording and its transcript → phone segments (`coartic align`), for the runtime to animate.

Two ways to find where each phone of the transcript lies in the recording:

- alignment by synthesis (`coartic.align.dtw`, any language a TTS speaks): a TTS that reports its
  phone times (Festival for Italian and English, espeak-ng's phoneme events for German and the
  other languages it knows) says the transcript; dynamic time warping of the MFCC sequences of the
  synthetic and the real speech carries the synthetic phone boundaries onto the recording (the
  approach of aeneas, at phone level);
- PocketSphinx (`coartic.align.sphinx`, English): forced alignment with its acoustic model and
  dictionary, and, without a transcript, phone recognition (as Rhubarb Lip Sync does).

docs/ALIGN.md gives the measured accuracy of each against MAUS labels and against the lips.
"""
