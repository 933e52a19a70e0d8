"""V+ reserved words: the keywords a V+ program may not use as a variable or program name.

Sources (see docs/real-cell.md, "The Adept controller (V+)"):

- V+ Language User's Guide v17, "Variable Name Requirements" (p. 99,
  http://38.142.81.21:8001/manual/vax/v-006u/user-s-guide-english/page-99.html): keywords
  reserved by Adept cannot be used as names; the list is the V+ Language Reference Guide's.
- V+ Language Reference Guide (Adept, http://www1.adept.com/main/KE/DATA/V%20Plus/
  V%20Language%20Reference/): its keyword index of program instructions, functions, system
  switches, parameters and monitor commands, from which this list is drawn.

NOT CONFIRMED: the full keyword index could not be read through the search tool (only single
keyword pages such as TRANS were found), so this list was compiled from the Reference Guide's
keyword index as remembered and is incomplete: a name accepted here may still be reserved, a
name refused here is reserved. Options (AdeptVision, AdeptMotion, AIM) reserve more words.
"""

from __future__ import annotations

# program instructions and their keywords
_INSTRUCTIONS = """
ABORT ABOVE ACCEL ALIGN ALTER ALTOFF ALTON ALWAYS AMOVE ANY APPRO APPROS ATTACH AUTO BASE
BELOW BITS BRAKE BREAK BY CALIBRATE CALL CALLP CALLS CASE CLEAR.EVENT CLOSE CLOSEI COARSE
CPOFF CPON CYCLE.END DECOMPOSE DEF.DIO DEFBELT DELAY DEPART DEPARTS DETACH DISABLE DO DRIVE
DURATION ELSE ENABLE END ESTOP EXECUTE EXIT FCLOSE FCMND FDELETE FEMPTY FINE FLIP FOPEN
FOPENA FOPEND FOPENR FOPENW FOR FSEEK GLOBAL GOTO HALT HERE IF IGNORE KEYMODE KILL LEFTY
LOCAL LOCK MC MCS MOVE MOVEC MOVEF MOVES MOVESF MOVET MOVEST MULTIPLE NEXT NOFLIP NONULL
NOOVERLAP NULL OF OPEN OPENI OVERLAP PANIC PAUSE PDNT.CLEAR PDNT.WRITE PENDANT PROCEED
PROMPT REACT REACTE REACTI READ READY RELAX RELAXI RELEASE RESET RETRY RETURN RETURNE
RIGHTY RUNSIG SELECT SET SET.EVENT SETBELT SETDEVICE SIGNAL SINGLE SOLVE.ANGLES SOLVE.FLAGS
SPEED STOP SWITCH TAS THEN TIMER TO TOOL TYPE UNTIL VALUE WAIT WAIT.EVENT WHILE WINDOW WRITE
"""

# functions (real-valued, string, transformation and precision-point)
_FUNCTIONS = """
ABS ACCEL ASC ATAN2 BASE BELT BITS BMASK BSTATUS CAS COS DBLB DCB DEFINED DEST DEVICE
DISTANCE DX DY DZ ERROR FLTB FRACT FRAME GET.EVENT GETC HERE HOUR.METER ID IDENTICAL INRANGE
INT INTB INVERSE IOSTAT IOTAS LAST LATCH LATCHED LEN LNGB MAX MIN NORM NORMAL OUTSIDE
PARAMETER POS PRIORITY RANDOM SCALE SHIFT SIG SIG.INS SIGN SIN SQR SQRT STATE STATUS TASK
TIME TPS TRANS TRANSB TRUNC VAL VLOCATION
$CHR $DBLB $DECODE $DEFAULT $ENCODE $ERROR $FLTB $INTB $LNGB $MID $SYMBOL $TIME $TRANSB
$TRUNCATE $UNPACK #PDEST #PHERE #PLATCH #PPOINT
"""

# operators and constants
_OPERATORS = "AND BAND BOR BXOR COM FALSE MOD NOT OFF ON OR PI TRUE XOR"

# system switches and parameters
_SYSTEM = """
AUTO.POWER.OFF BELT.MODE CP DECEL.100 DRY.RUN FORCE HAND.TIME INTERACTIVE MESSAGES
NOT.CALIBRATED OBSTACLE POWER ROBOT SCALE.ACCEL SCREEN.TIMEOUT SET.SPEED TERMINAL TRACE
UPPER
"""

# monitor commands (a program name equal to one is refused by LOAD in some releases)
_MONITOR = """
COPY DELETE DIRECTORY EDIT FREE LIST LOAD PRIME SEE SSTEP STORE XSTEP ZERO
"""


def _words(*blocks: str) -> frozenset[str]:
    return frozenset(w for block in blocks for w in block.split())


_ALL = _words(_INSTRUCTIONS, _FUNCTIONS, _OPERATORS, _SYSTEM, _MONITOR)
RESERVED: frozenset[str] = frozenset(w for w in _ALL if w[0] not in "$#")
SIGIL_RESERVED: frozenset[str] = frozenset(w for w in _ALL if w[0] in "$#")


def reserved(name: str) -> bool:
    """Is ``name`` (with its ``$``/``#``/``%`` sigil, any case) a V+ keyword?"""
    up = name.upper()
    return up.lstrip("$#%") in RESERVED or up in SIGIL_RESERVED
