"""The V+ keyword index: the words a V+ program may not use as a name, and the instructions
a program step may start with.

Sources (docs/real-cell.md, "The Adept controller (V+)"):

- V+ Language User's Guide v17, "Variable Name Requirements" (p. 99,
  http://38.142.81.21:8001/manual/vax/v-006u/user-s-guide-english/page-99.html): "Keywords
  reserved by Adept cannot be used. The V+ Language Reference Guide lists the basic
  keywords"; names are letters, digits, ``.`` and ``_``; the page's own example of a
  reserved word is ``pi``. User's Guide p. 35 ("Program Lines"): the operation of a step
  "must be a valid V+ language keyword"; options (AdeptVision) add instructions.
- V+ Language Reference Guide v17 (Adept, http://www1.adept.com/main/KE/DATA/V%20Plus/
  V%20Language%20Reference/): one page per keyword. Pages read through the search tool:
  TRANS, SHIFT, SCALE (transformation functions), DX/DY/DZ (``dx_r.html``, whose "Related
  Keywords" names the "RX, RY, RZ transformation functions": this is where ``rz`` as a
  variable name is refused from).
- V+ Language User's Guide v17 pp. 33-34 (REACTI, BRAKE, ATTACH, DRY.RUN), p. 45 (CALL,
  EXECUTE, DEFINED), p. 47 (REACT, REACTI, REACTE, LOCK, PRIORITY).
- Cross-check: an ANTLR grammar of VAL II, V+'s predecessor (``Val2Parser.java``, found
  with find_string "DEFBELT"), whose token list agrees on the motion, belt and
  transformation words (APPRO, APPROS, DEFBELT, DECOMPOSE, INRANGE, INVERSE, FRAME, ...);
  its VAL-II-only words (ADC, DAC, GRASP, PCEXECUTE, ...) are not V+ and are not listed.

INCOMPLETE: the Reference Guide's keyword index itself could not be read whole through the
search tool, so the lists below were compiled from its per-keyword pages as known (V+ 12 to
17), category by category. A name refused here is a V+ keyword; a name accepted here may
still be reserved on a release or with an option (AdeptVision, AdeptMotion, AIM add many).
``LOAD`` on the controller is the final word (docs/real-cell.md, section 9).

Dotted names: a V+ name is one run of letters, digits, ``.`` and ``_`` (User's Guide p. 99,
rule 3), and V+'s own keywords contain periods (``DRY.RUN``, ``SIG.INS``, ``CLEAR.EVENT``),
so ``rz.max`` is one word, not ``RZ`` followed by ``.max``, and is not a keyword. The check
is therefore on the whole name: ``rz`` and ``$rz`` are refused, ``rz.max``, ``stop.req`` and
``move.loc`` are not. NOT CONFIRMED on a controller (no page says it in so many words).
"""

from __future__ import annotations

# Program instructions: the words a program step may start with (Reference Guide, the
# "program instruction" pages).
INSTRUCTIONS_TEXT = """
ABORT ACCEL AIO.OUT ALIGN ALTER ALTOFF ALTON AMOVE ANY APPRO APPROS ATTACH AUTO BASE BITS
BRAKE BREAK CALIBRATE CALL CALLP CALLS CASE CLEAR.EVENT CLOSE CLOSEI COARSE CPOFF CPON
CYCLE.END DECOMPOSE DEF.DIO DEFBELT DELAY DEPART DEPARTS DETACH DISABLE DO DRIVE DURATION
ELSE ENABLE END ESTOP EXECUTE EXIT FCLOSE FCMND FCOPY FDELETE FEMPTY FINE FLIP FOPEN FOPENA
FOPEND FOPENR FOPENW FOR FSEEK FSET GLOBAL GOTO HALT HERE IF IGNORE IOPUTB IOPUTD IOPUTF
IOPUTS KEYMODE KILL LEFTY LOCAL LOCK MC MCS MOVE MOVEC MOVEF MOVES MOVESF MOVET MOVEST
MULTIPLE NEXT NOFLIP NONULL NOOVERLAP NULL OPEN OPENI OVERLAP PACK PANIC PARAMETER PAUSE
PDNT.CLEAR PDNT.WRITE PROCEED PROMPT REACT REACTE REACTI READ READY RELAX RELAXI RELEASE
RESET RETRY RETURN RETURNE RIGHTY RUNSIG SELECT SET SET.EVENT SETBELT SETDEVICE SIGNAL
SINGLE SOLVE.ANGLES SOLVE.FLAGS SOLVE.TRANS SPEED STOP SWITCH TIMER TOOL TYPE UNTIL VALUE
WAIT WAIT.EVENT WAIT.START WHILE WINDOW WRITE
"""

# Words that only appear inside an instruction (its clauses), never at the start of a step.
_CLAUSES = "ALWAYS BY OF STEP THEN TO ABOVE BELOW REAL DOUBLE LOC"

# Functions: real-valued, string, transformation and precision-point (the "function" pages).
_FUNCTIONS = """
ABS ACCEL AIO.IN AIO.INS ASC ATAN2 BASE BELT BITS BMASK BSTATUS CAS CONFIG COS DBLB DCB
DEFINED DEST DEVICE DISTANCE DURATION DX DY DZ ERROR FLTB FRACT FRAME FREE GET.EVENT GETC
HAND HERE HOUR.METER ID IDENTICAL INRANGE INT INTB INVERSE IOGETB IOGETD IOGETF IOGETS
IOSTAT IOTAS LAST LATCH LATCHED LEN LNGB MAX MIN NORM NORMAL NULL OUTSIDE PARAMETER PENDANT
POS PRIORITY RANDOM RX RY RZ SCALE SELECT SHIFT SIG SIG.INS SIGN SIN SPEED SQR SQRT STATE
STATUS SWITCH SYMBOL.PTR TAS TASK TIME TIMER TOOL TPS TRANS TRANSB TRUNC VAL VLOCATION
$CHR $DBLB $DECODE $DEFAULT $ENCODE $ERROR $FLTB $ID $INTB $LNGB $MID $SYMBOL $TIME
$TRANSB $TRUNCATE $UNPACK #PDEST #PHERE #PLATCH #PPOINT
"""

# Operators and constants (``pi`` is the User's Guide's own example of a reserved word).
_OPERATORS = "AND BAND BOR BXOR COM FALSE MOD NOT OFF ON OR PI TRUE XOR"

# System switches and parameters (ENABLE / DISABLE / SWITCH, PARAMETER pages).
_SYSTEM = """
AUTO.POWER.OFF BELT BELT.MODE CP DECEL.100 DRY.RUN FORCE HAND.TIME INTERACTIVE KERMIT.RETRY
KERMIT.TIMEOUT MCP.MESSAGE MCS.MESSAGE MESSAGES MONITORS NETWORK NOT.CALIBRATED OBSTACLE
POWER ROBOT SCALE.ACCEL SCREEN.TIMEOUT SET.SPEED TERMINAL TRACE UPPER
"""

# Monitor commands (V+ Operating System Reference Guide; a program named after one cannot
# be run from the monitor by name, and several are also program instructions).
_MONITOR = """
BPT CD COMMANDS COPY DEFAULT DELETE DELETEL DELETEM DELETEP DELETER DELETES DIRECTORY EDIT
FDIRECTORY FLIST FORMAT FRENAME INSTALL IO JOG LIST LISTL LISTP LISTR LISTS LOAD MDIRECTORY
MODULE NET POINT PRIME RENAME SEE SSTEP STACK STORE STOREL STOREM STOREP STORER STORES TEACH
TESTP WHERE XSTEP ZERO
"""

# Motion instructions: each only starts a motion; the program runs on while the arm moves
# (forward processing: User's Guide v12 chapter 8, "Motion Control Instructions",
# https://1library.net/article/motion-control-instructions-language-user-guide-version.ye06vg1q).
# DELAY is a motion in V+ (the arm holds still for the time) -- NOT CONFIRMED, see
# docs/real-cell.md, "What the programs rely on".
MOTION: frozenset[str] = frozenset("""
ALIGN AMOVE APPRO APPROS DELAY DEPART DEPARTS DRIVE MOVE MOVEC MOVEF MOVES MOVESF MOVET
MOVEST READY
""".split())


def _words(*blocks: str) -> frozenset[str]:
    return frozenset(w for block in blocks for w in block.split())


INSTRUCTIONS: frozenset[str] = _words(INSTRUCTIONS_TEXT)
_ALL = _words(INSTRUCTIONS_TEXT, _CLAUSES, _FUNCTIONS, _OPERATORS, _SYSTEM, _MONITOR)
RESERVED: frozenset[str] = frozenset(w for w in _ALL if w[0] not in "$#")
SIGIL_RESERVED: frozenset[str] = frozenset(w for w in _ALL if w[0] in "$#")


def reserved(name: str) -> bool:
    """Is ``name`` (with its ``$``/``#``/``%`` sigil, any case) a V+ keyword? The whole
    name counts: ``rz`` is, ``rz.max`` is not (module docstring, "Dotted names")."""
    up = name.upper()
    return up.lstrip("$#%") in RESERVED or up in SIGIL_RESERVED
