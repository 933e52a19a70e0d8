MODULE FeederParts
    ! feeder_bt part server: a pick-and-place loop for an ABB robot (RAPID, IRC5 with the
    ! socket messaging option). Protocol: docs/part-server.md.
    !
    ! Settings: the cell's address and port, the work object of the belt, the tool and the
    ! place target. Conveyor tracking on IRC5 is its own option (a coordinated work object
    ! on the conveyor, which the controller starts from a sync signal); this loop instead
    ! uses the offer's latch and the belt speed, which works for a belt that stands still
    ! while the robot picks (incremental mode) and is where a tracking set-up plugs in.
    ! To confirm on your RobotWare (not checked against a controller here): SocketReceive's
    ! \Time argument, and StrFind/StrPart/StrToVal as used below.

    CONST string FEEDER_IP := "192.168.125.10";
    CONST num FEEDER_PORT := 7600;
    ! Who this robot is. RAPID has no SHA-256 or HMAC function that we could find, so it
    ! cannot answer the part server's challenge (HELLO NAME, then PROOF HMAC-SHA256). List
    ! the controller's address in the robots file (no HELLO: leave ROBOT_NAME empty), or, on
    ! a trusted, isolated robot network only, opt this robot in to the old plain form
    ! (python -m feeder_bt.plant.robots add irb1 --robots FILE --plain-secret): that line
    ! can be captured and replayed (docs/part-server.md, "Robots must be trusted").
    CONST string ROBOT_NAME := "";
    CONST string ROBOT_SECRET := "";
    PERS tooldata tSuction := [TRUE, [[0, 0, 100], [1, 0, 0, 0]], [0.5, [0, 0, 50], [1, 0, 0, 0], 0, 0, 0]];
    PERS wobjdata wBelt := [FALSE, TRUE, "", [[0, 0, 0], [1, 0, 0, 0]], [[0, 0, 0], [1, 0, 0, 0]]];
    CONST robtarget pPlace := [[300, -250, 50], [0, 0, 1, 0], [0, 0, 0, 0], [9E9, 9E9, 9E9, 9E9, 9E9, 9E9]];
    VAR socketdev feeder;

    PROC Feed()
        VAR string reply;
        VAR string id;
        VAR num x;
        VAR num y;
        VAR num rz;
        VAR bool ok;
        VAR robtarget pGrip;
        SocketCreate feeder;
        SocketConnect feeder, FEEDER_IP, FEEDER_PORT;
        Hello;
        WHILE TRUE DO
            reply := Call("PART WAIT 5");
            IF Field(reply, 1) = "PART" THEN
                id := Field(reply, 2);
                ok := StrToVal(Field(reply, 4), x);
                ok := StrToVal(Field(reply, 5), y);
                ok := StrToVal(Field(reply, 7), rz);
                pGrip := [[x, y, 0], OrientZYX(rz, 0, 180), [0, 0, 0, 0], [9E9, 9E9, 9E9, 9E9, 9E9, 9E9]];
                MoveJ Offs(pGrip, 0, 0, 30), v1000, z5, tSuction \WObj:=wBelt;
                MoveL pGrip, v500, fine, tSuction \WObj:=wBelt;
                SetDO doSuction, 1;
                WaitTime 0.1;
                MoveL Offs(pGrip, 0, 0, 30), v500, z5, tSuction \WObj:=wBelt;
                IF DInput(diVacuum) = 1 THEN
                    reply := Call("PICKED " + id);
                    MoveJ Offs(pPlace, 0, 0, 30), v1000, z5, tSuction;
                    MoveL pPlace, v500, fine, tSuction;
                    SetDO doSuction, 0;
                    MoveL Offs(pPlace, 0, 0, 30), v500, z5, tSuction;
                    reply := Call("PLACED " + id);
                ELSE
                    SetDO doSuction, 0;
                    reply := Call("MISSED " + id + " nothing held");
                ENDIF
            ENDIF
        ENDWHILE
    ERROR
        IF ERRNO = ERR_SOCK_CLOSED OR ERRNO = ERR_SOCK_TIMEOUT THEN
            ! the cell counts a part we took and never reported once its time-out ends
            SocketClose feeder;
            WaitTime 2;
            SocketCreate feeder;
            SocketConnect feeder, FEEDER_IP, FEEDER_PORT;
            Hello;
            RETRY;
        ENDIF
    ENDPROC

    ! say who this robot is (the plain form: see ROBOT_NAME above), once per connection
    PROC Hello()
        VAR string reply;
        IF ROBOT_NAME <> "" THEN
            reply := Call("HELLO " + ROBOT_NAME + " " + ROBOT_SECRET);
            IF Field(reply, 1) <> "HELLO" THEN
                ErrWrite "feeder: refused", reply;
                Stop;
            ENDIF
        ENDIF
    ENDPROC

    ! one request line, one reply line
    FUNC string Call(string line)
        VAR string reply;
        SocketSend feeder \Str:=line + "\0A";
        SocketReceive feeder \Str:=reply \Time:=15;
        RETURN reply;
    ENDFUNC

    ! the n-th space-separated field of a reply (0 is "OK" or "ERR")
    FUNC string Field(string reply, num n)
        VAR num start := 1;
        VAR num stop;
        FOR i FROM 1 TO n DO
            start := StrFind(reply, start, " ") + 1;
        ENDFOR
        stop := StrFind(reply, start, " " + "\0A");
        RETURN StrPart(reply, start, stop - start);
    ENDFUNC
ENDMODULE
